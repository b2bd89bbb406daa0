//! Image error against a reference, measured where a person sees it: on the
//! sRGB-encoded values in [0, 1] (before 8-bit rounding), over all channels.

use crate::error::{Error, Result};
use crate::render::srgb::linear_to_srgb;
use crate::render::Frame;

fn same_size(a: &Frame, b: &Frame) -> Result<()> {
    if (a.width, a.height) != (b.width, b.height) || a.pixels.len() != b.pixels.len() {
        return Err(Error::Other(format!(
            "image sizes differ: {}x{} against {}x{}",
            a.width, a.height, b.width, b.height
        )));
    }
    Ok(())
}

/// Root-mean-square difference of the display values of `a` and `b`.
pub fn rmse(a: &Frame, b: &Frame) -> Result<f64> {
    same_size(a, b)?;
    let sum: f64 = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .map(|(p, q)| {
            (0..3)
                .map(|c| {
                    let d = linear_to_srgb(p[c]) as f64 - linear_to_srgb(q[c]) as f64;
                    d * d
                })
                .sum::<f64>()
        })
        .sum();
    Ok((sum / (3 * a.pixels.len().max(1)) as f64).sqrt())
}

/// Peak signal-to-noise ratio in dB for a peak of 1 (infinite for equal images).
pub fn psnr(rmse: f64) -> f64 {
    if rmse > 0.0 {
        -20.0 * rmse.log10()
    } else {
        f64::INFINITY
    }
}

/// An 8-bit picture of `|a - b|` in display values times `gain`, and the number of
/// pixels whose 8-bit values differ.
pub fn difference_image(a: &Frame, b: &Frame, gain: f32) -> Result<(Vec<u8>, usize)> {
    same_size(a, b)?;
    let mut differing = 0;
    let mut out = Vec::with_capacity(a.pixels.len() * 3);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        let mut differs = false;
        for c in 0..3 {
            let (x, y) = (linear_to_srgb(p[c]), linear_to_srgb(q[c]));
            differs |= (x * 255.0 + 0.5) as u8 != (y * 255.0 + 0.5) as u8;
            out.push(((x - y).abs() * gain * 255.0).min(255.0) as u8);
        }
        differing += differs as usize;
    }
    Ok((out, differing))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use glam::Vec3;

    fn frame(pixels: Vec<Vec3>) -> Frame {
        Frame {
            width: pixels.len() as u32,
            height: 1,
            pixels,
        }
    }

    #[test]
    fn zero_for_identical_images_and_growing_with_noise() {
        let mut rng = Rng::for_pixel(0, 7, 0);
        let base: Vec<Vec3> = (0..4096)
            .map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 0.8)
            .collect();
        let reference = frame(base.clone());
        assert_eq!(rmse(&reference, &reference).unwrap(), 0.0);
        assert_eq!(psnr(0.0), f64::INFINITY);
        let mut last = 0.0;
        for amplitude in [0.001, 0.01, 0.05, 0.2] {
            let noisy = frame(
                base.iter()
                    .map(|p| {
                        *p + (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5)
                            * amplitude
                    })
                    .collect(),
            );
            let e = rmse(&noisy, &reference).unwrap();
            assert!(e > last, "{amplitude}: {e} <= {last}");
            assert!(psnr(e) < psnr(last.max(1e-12)));
            last = e;
        }
        let (img, n) = difference_image(&reference, &reference, 8.0).unwrap();
        assert_eq!(n, 0);
        assert!(img.iter().all(|&b| b == 0));
        let other = frame(vec![Vec3::ONE; 4096]);
        assert_eq!(difference_image(&reference, &other, 1.0).unwrap().1, 4096);
        assert!(rmse(&reference, &frame(vec![Vec3::ONE; 3])).is_err());
    }
}
