//! From linear radiance to 8-bit pixels: clamp to [0, 1], encode with the
//! sRGB transfer curve, and hash the bytes (equal hashes, equal images).

use super::Frame;

/// The sRGB transfer function applied to a clamped linear value (NaN as 0).
#[inline]
pub fn linear_to_srgb(x: f32) -> f32 {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// [`linear_to_srgb`] rounded to 8 bits.
#[inline]
pub fn linear_to_srgb8(x: f32) -> u8 {
    (linear_to_srgb(x) * 255.0 + 0.5) as u8
}

/// The frame as 8-bit sRGB, RGB interleaved, row 0 at the top.
pub fn to_srgb8(frame: &Frame) -> Vec<u8> {
    frame
        .pixels
        .iter()
        .flat_map(|p| [p.x, p.y, p.z].map(linear_to_srgb8))
        .collect()
}

/// FNV-1a 64 of the 8-bit pixels, as 16 hex digits: equal hashes mean equal images.
pub fn image_hash(rgb8: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in rgb8 {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_endpoints_and_midtone() {
        assert_eq!(linear_to_srgb8(0.0), 0);
        assert_eq!(linear_to_srgb8(1.0), 255);
        assert_eq!(linear_to_srgb8(7.0), 255);
        assert_eq!(linear_to_srgb8(-1.0), 0);
        assert_eq!(linear_to_srgb8(f32::NAN), 0);
        assert_eq!(linear_to_srgb8(0.2159), 128); // sRGB 0.5 is linear 0.214; 128/255 is 0.2159
    }

    #[test]
    fn hash_changes_with_any_byte() {
        let a = vec![0u8; 30];
        let mut b = a.clone();
        b[17] = 1;
        assert_ne!(image_hash(&a), image_hash(&b));
        assert_eq!(image_hash(&a), image_hash(&a.clone()));
    }
}
