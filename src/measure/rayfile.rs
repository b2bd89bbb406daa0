//! Ray files: the recorded ray sets in a documented binary format, so that
//! rays made by any tool can be traced and judged by raylab (`raylab rays`
//! writes them; `validate --rays` and `bench --rays` read them).
//!
//! Little-endian throughout:
//!
//! | offset | size | field |
//! |---:|---:|---|
//! | 0 | 8 | magic `RAYLABRY` |
//! | 8 | 4 | version, u32 = 1 |
//! | 12 | 4 | bytes per ray, u32 = 36 |
//! | 16 | 8 | ray count N, u64 |
//! | 24 | 40 | rays of each kind, 5 x u64 (primary, shadow, ao, diffuse, random); they sum to N |
//! | 64 | 36 N | the rays |
//!
//! A ray: origin (3 x f32), direction (3 x f32), tmin (f32), tmax (f32), kind
//! (u32: 0 primary, 1 shadow, 2 ao, 3 diffuse, 4 random). Primary, diffuse and
//! random rays ask for the closest hit, shadow and AO rays for any hit.
//! Rays need not be valid (NaN and zero directions are legitimate test
//! input: every backend must answer them with a miss).

use std::path::Path;

use glam::Vec3;

use crate::error::{Error, Result};
use crate::geometry::Ray;
use crate::measure::validate::RaySet;

pub const MAGIC: &[u8; 8] = b"RAYLABRY";
pub const VERSION: u32 = 1;
pub const HEADER_BYTES: usize = 64;
pub const RAY_BYTES: usize = 36;

/// Rays grouped by kind.
pub type RaySets = Vec<(RaySet, Vec<Ray>)>;

/// The kinds in file order (the `kind` field indexes this).
pub const KINDS: [RaySet; 5] = [
    RaySet::Primary,
    RaySet::Shadow,
    RaySet::Ao,
    RaySet::Diffuse,
    RaySet::Random,
];

fn kind_index(set: RaySet) -> u32 {
    KINDS.iter().position(|&k| k == set).unwrap_or(0) as u32
}

/// The bytes of a ray file holding `sets`.
pub fn encode(sets: &[(RaySet, Vec<Ray>)]) -> Vec<u8> {
    let total: usize = sets.iter().map(|(_, r)| r.len()).sum();
    let mut out = Vec::with_capacity(HEADER_BYTES + RAY_BYTES * total);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(RAY_BYTES as u32).to_le_bytes());
    out.extend_from_slice(&(total as u64).to_le_bytes());
    for kind in KINDS {
        let n: usize = sets
            .iter()
            .filter(|(s, _)| *s == kind)
            .map(|(_, r)| r.len())
            .sum();
        out.extend_from_slice(&(n as u64).to_le_bytes());
    }
    for (set, rays) in sets {
        for r in rays {
            for v in r.origin.to_array().into_iter().chain(r.dir.to_array()) {
                out.extend_from_slice(&v.to_le_bytes());
            }
            out.extend_from_slice(&r.tmin.to_le_bytes());
            out.extend_from_slice(&r.tmax.to_le_bytes());
            out.extend_from_slice(&kind_index(*set).to_le_bytes());
        }
    }
    out
}

/// Writes `sets` to `path` (atomically, as every file raylab writes).
pub fn write(path: &Path, sets: &[(RaySet, Vec<Ray>)]) -> Result<()> {
    let bytes = encode(sets);
    crate::output::write_atomic(path, |w| std::io::Write::write_all(w, &bytes))
}

/// Reads a ray file: its rays grouped by kind, in [`KINDS`] order, kinds
/// without rays left out.
pub fn read(path: &Path) -> Result<RaySets> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode(&bytes).map_err(|(offset, msg)| Error::Parse {
        path: path.to_path_buf(),
        line: 0,
        msg: format!("byte offset {offset}: {msg}"),
    })
}

/// Parses ray-file bytes; an error names the byte offset at fault.
pub fn decode(bytes: &[u8]) -> std::result::Result<RaySets, (usize, String)> {
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let u64_at = |o: usize| u64::from_le_bytes(bytes[o..o + 8].try_into().unwrap());
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        return Err((0, "not a raylab ray file (no RAYLABRY magic)".into()));
    }
    if bytes.len() < HEADER_BYTES {
        return Err((
            bytes.len(),
            format!("truncated header ({} of {HEADER_BYTES} bytes)", bytes.len()),
        ));
    }
    let version = u32_at(8);
    if version != VERSION {
        return Err((8, format!("version {version}, this raylab reads {VERSION}")));
    }
    let ray_bytes = u32_at(12) as usize;
    if ray_bytes != RAY_BYTES {
        return Err((
            12,
            format!("{ray_bytes} bytes per ray, expected {RAY_BYTES}"),
        ));
    }
    let total = u64_at(16);
    let counts: Vec<u64> = (0..KINDS.len()).map(|k| u64_at(24 + 8 * k)).collect();
    let sum = counts.iter().try_fold(0u64, |a, &c| a.checked_add(c));
    if sum != Some(total) {
        return Err((
            24,
            format!("the kinds' counts do not sum to the ray count {total}"),
        ));
    }
    let expected = (total as u128) * RAY_BYTES as u128 + HEADER_BYTES as u128;
    if (bytes.len() as u128) < expected {
        let whole = (bytes.len() - HEADER_BYTES) / RAY_BYTES;
        return Err((
            HEADER_BYTES + whole * RAY_BYTES,
            format!("truncated: the header says {total} rays, the file holds {whole} whole ones"),
        ));
    }
    if (bytes.len() as u128) > expected {
        return Err((
            expected as usize,
            format!(
                "{} bytes after the {total} rays",
                bytes.len() as u128 - expected
            ),
        ));
    }
    let mut sets: RaySets = KINDS.iter().map(|&k| (k, Vec::new())).collect();
    for i in 0..total as usize {
        let o = HEADER_BYTES + i * RAY_BYTES;
        let v = |k: usize| f32_at(o + 4 * k);
        let kind = u32_at(o + 32);
        let Some(set) = sets.get_mut(kind as usize) else {
            return Err((o + 32, format!("ray {i} has kind {kind} (0..=4)")));
        };
        set.1.push(Ray::segment(
            Vec3::new(v(0), v(1), v(2)),
            Vec3::new(v(3), v(4), v(5)),
            v(6),
            v(7),
        ));
    }
    for (k, (set, rays)) in sets.iter().enumerate() {
        if rays.len() as u64 != counts[k] {
            return Err((
                24 + 8 * k,
                format!(
                    "the header counts {} {} rays, the file holds {}",
                    counts[k],
                    set.name(),
                    rays.len()
                ),
            ));
        }
    }
    sets.retain(|(_, r)| !r.is_empty());
    Ok(sets)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<(RaySet, Vec<Ray>)> {
        vec![
            (
                RaySet::Primary,
                vec![Ray::new(
                    Vec3::new(0.0, 1.0, 3.0),
                    Vec3::new(0.1, 0.0, -1.0),
                )],
            ),
            (
                RaySet::Ao,
                vec![
                    Ray::segment(Vec3::ZERO, Vec3::Y, 0.0, 0.2),
                    Ray::segment(Vec3::X, Vec3::NAN, 1e-4, f32::INFINITY),
                ],
            ),
        ]
    }

    #[test]
    fn a_file_reads_back_bit_for_bit() {
        let bytes = encode(&sample());
        assert_eq!(bytes.len(), HEADER_BYTES + 3 * RAY_BYTES);
        let back = decode(&bytes).unwrap();
        assert_eq!(back.len(), 2);
        for ((a, ra), (b, rb)) in back.iter().zip(&sample()) {
            assert_eq!(a, b);
            for (x, y) in ra.iter().zip(rb) {
                let bits = |r: &Ray| {
                    [r.origin.to_array(), r.dir.to_array()]
                        .concat()
                        .iter()
                        .chain([&r.tmin, &r.tmax])
                        .map(|f| f.to_bits())
                        .collect::<Vec<_>>()
                };
                assert_eq!(bits(x), bits(y));
            }
        }
    }

    #[test]
    fn malformed_files_name_the_offset() {
        let good = encode(&sample());
        let err = |bytes: &[u8]| decode(bytes).unwrap_err();
        assert_eq!(err(b"PLY\n").0, 0);
        assert_eq!(err(&good[..40]).0, 40);
        let mut v = good.clone();
        v[8] = 2;
        assert_eq!(err(&v).0, 8);
        let mut v = good.clone();
        v[12] = 32;
        assert_eq!(err(&v).0, 12);
        let mut v = good.clone();
        v[24] = 5;
        assert_eq!(err(&v).0, 24);
        // Truncated inside the second ray: the offset of the first missing whole ray.
        let (offset, msg) = err(&good[..HEADER_BYTES + RAY_BYTES + 10]);
        assert_eq!(offset, HEADER_BYTES + RAY_BYTES);
        assert!(msg.contains("truncated"), "{msg}");
        let mut v = good.clone();
        v.push(0);
        assert_eq!(err(&v).0, good.len());
        let mut v = good.clone();
        let kind = HEADER_BYTES + RAY_BYTES + 32;
        v[kind] = 9;
        assert_eq!(err(&v).0, kind);
        // A kind that contradicts the header's counts.
        let mut v = good.clone();
        v[HEADER_BYTES + 32] = 1;
        assert_eq!(err(&v).0, 24);
    }
}
