//! The decompressed payload of a chunk file: blocks to named byte planes and back, for both
//! layouts (`formats/chunk.md`, "Payload"): versions 1 and 2 store TSDF deltas along the coded
//! voxels, colour as is and `u − f`; version 3 stores residuals of [`predict`].

use super::predict::{clamp_i16, clamp_u8, predict, predict_u};
use super::{CodecError, BLOCK_DENSE, BLOCK_HAS_REGULARIZED};
use crate::grid::{Block, VOXELS_PER_BLOCK};

const VB: usize = VOXELS_PER_BLOCK;

/// Whether the empty voxels of `b` (weight/Ω byte 0) all hold the defaults (TSDF +1, colour 0,
/// `u = f`), so that only its non-empty voxels need coding.
pub fn sparse_ok(b: &Block) -> bool {
    let t0 = Block::default().tsdf[0];
    (0..VB).all(|i| {
        b.weight_omega[i] != 0
            || (b.tsdf[i] == t0
                && b.color[i] == [0; 3]
                && b.regularized.as_ref().is_none_or(|u| u[i] == b.tsdf[i]))
    })
}

/// Which voxels of a block are coded.
pub fn coded_mask(weight_omega: &[u8; VB], dense: bool) -> [bool; VB] {
    std::array::from_fn(|i| dense || weight_omega[i] != 0)
}

#[inline]
fn zigzag(d: i16) -> u16 {
    ((d << 1) ^ (d >> 15)) as u16
}

#[inline]
fn unzigzag(z: u16) -> i16 {
    ((z >> 1) as i16) ^ -((z & 1) as i16)
}

/// The payload's parts, in file order, with their names (what a per-field size study compresses
/// one by one): coordinates, block flags, weights, TSDF low and high bytes, red, green, blue, `u`
/// low and high bytes. `order` is sorted by local coordinate; `predicted` selects format 3.
pub fn payload_planes(
    order: &[([u8; 3], &Block)],
    predicted: bool,
) -> Vec<(&'static str, Vec<u8>)> {
    let flags: Vec<u8> = order
        .iter()
        .map(|(_, b)| {
            (if b.regularized.is_some() {
                BLOCK_HAS_REGULARIZED
            } else {
                0
            }) | (if sparse_ok(b) { 0 } else { BLOCK_DENSE })
        })
        .collect();
    let (mut tsdf, mut rgb, mut reg) =
        (Vec::new(), [Vec::new(), Vec::new(), Vec::new()], Vec::new());
    for ((_, b), f) in order.iter().zip(&flags) {
        let coded = coded_mask(&b.weight_omega, f & BLOCK_DENSE != 0);
        if predicted {
            residuals_v3(b, &coded, &mut tsdf, &mut rgb, &mut reg);
        } else {
            let mut prev = 0i16;
            for i in (0..VB).filter(|&i| coded[i]) {
                tsdf.push(zigzag(b.tsdf[i].wrapping_sub(prev)));
                prev = b.tsdf[i];
                for (ch, plane) in rgb.iter_mut().enumerate() {
                    plane.push(b.color[i][ch]);
                }
                if let Some(u) = &b.regularized {
                    reg.push(zigzag(u[i].wrapping_sub(b.tsdf[i])));
                }
            }
        }
    }
    let lo = |z: &[u16]| z.iter().map(|v| (*v & 0xff) as u8).collect::<Vec<u8>>();
    let hi = |z: &[u16]| z.iter().map(|v| (*v >> 8) as u8).collect::<Vec<u8>>();
    let [r, g, b] = rgb;
    vec![
        ("coordinates", order.iter().flat_map(|(l, _)| *l).collect()),
        ("block flags", flags),
        (
            "weight + omega",
            order.iter().flat_map(|(_, b)| b.weight_omega).collect(),
        ),
        ("tsdf low", lo(&tsdf)),
        ("tsdf high", hi(&tsdf)),
        ("red", r),
        ("green", g),
        ("blue", b),
        ("u low", lo(&reg)),
        ("u high", hi(&reg)),
    ]
}

/// Format-3 residuals of one block's coded voxels, appended to the planes.
fn residuals_v3(
    b: &Block,
    coded: &[bool; VB],
    tsdf: &mut Vec<u16>,
    rgb: &mut [Vec<u8>; 3],
    reg: &mut Vec<u16>,
) {
    let f: [i32; VB] = std::array::from_fn(|i| b.tsdf[i] as i32);
    let mut ef = [0i32; VB];
    let mut prev = 0;
    for i in (0..VB).filter(|&i| coded[i]) {
        let p = clamp_i16(predict(&f, coded, i, prev));
        tsdf.push(zigzag(b.tsdf[i].wrapping_sub(p)));
        ef[i] = f[i] - p as i32;
        prev = f[i];
    }
    // Each channel's residual, stored less the previous channel's (0 for grey voxels).
    let mut before = [0u8; VB];
    for (ch, plane) in rgb.iter_mut().enumerate() {
        let c: [i32; VB] = std::array::from_fn(|i| b.color[i][ch] as i32);
        let mut prev = 0;
        for i in (0..VB).filter(|&i| coded[i]) {
            let r = b.color[i][ch].wrapping_sub(clamp_u8(predict(&c, coded, i, prev)));
            plane.push(r.wrapping_sub(before[i]));
            before[i] = r;
            prev = c[i];
        }
    }
    if let Some(u) = &b.regularized {
        let uv: [i32; VB] = std::array::from_fn(|i| u[i] as i32);
        let mut prev = 0;
        for i in (0..VB).filter(|&i| coded[i]) {
            let p = predict_u(clamp_i16(predict(&uv, coded, i, prev)), ef[i]);
            reg.push(zigzag(u[i].wrapping_sub(p)));
            prev = uv[i];
        }
    }
}

/// Reads the voxel planes (TSDF, colour, `u`: `rest`, the payload after the weights) into
/// `blocks`, whose weights are set; `flags` are the block flags, `k` and `k_reg` the coded voxels
/// in all blocks and in those with `u`.
pub fn read_voxel_planes<'a>(
    blocks: impl Iterator<Item = &'a mut Block>,
    flags: &[u8],
    predicted: bool,
    (k, k_reg): (usize, usize),
    rest: &[u8],
) -> Result<(), CodecError> {
    let mut at = 0usize;
    let mut take = |len: usize| -> Result<&[u8], CodecError> {
        let s = rest
            .get(at..at + len)
            .ok_or_else(|| CodecError::Malformed("payload shorter than its fields".into()))?;
        at += len;
        Ok(s)
    };
    let (tlo, thi) = (take(k)?, take(k)?);
    let planes = [take(k)?, take(k)?, take(k)?];
    let (ulo, uhi) = (take(k_reg)?, take(k_reg)?);
    let word = |lo: &[u8], hi: &[u8], j: usize| unzigzag(lo[j] as u16 | (hi[j] as u16) << 8);
    let (mut j, mut ju) = (0usize, 0usize);
    for (b, f) in blocks.zip(flags) {
        let coded = &coded_mask(&b.weight_omega, f & BLOCK_DENSE != 0);
        let j0 = j;
        let mut fv = [0i32; VB];
        let mut ef = [0i32; VB];
        let mut prev = 0i32;
        for i in (0..VB).filter(|&i| coded[i]) {
            let r = word(tlo, thi, j);
            b.tsdf[i] = if predicted {
                let p = clamp_i16(predict(&fv, coded, i, prev));
                let t = p.wrapping_add(r);
                ef[i] = t as i32 - p as i32;
                t
            } else {
                (prev as i16).wrapping_add(r)
            };
            fv[i] = b.tsdf[i] as i32;
            prev = fv[i];
            j += 1;
        }
        let mut before = [0u8; VB];
        for (ch, plane) in planes.iter().enumerate() {
            let mut c = [0i32; VB];
            let mut prev = 0i32;
            for (jj, i) in (j0..).zip((0..VB).filter(|&i| coded[i])) {
                b.color[i][ch] = if predicted {
                    let r = plane[jj].wrapping_add(before[i]);
                    before[i] = r;
                    r.wrapping_add(clamp_u8(predict(&c, coded, i, prev)))
                } else {
                    plane[jj]
                };
                c[i] = b.color[i][ch] as i32;
                prev = c[i];
            }
        }
        if f & BLOCK_HAS_REGULARIZED == 0 {
            continue;
        }
        let mut u = Box::new(b.tsdf);
        let mut uv = [0i32; VB];
        let mut prev = 0i32;
        for i in (0..VB).filter(|&i| coded[i]) {
            let r = word(ulo, uhi, ju);
            u[i] = if predicted {
                predict_u(clamp_i16(predict(&uv, coded, i, prev)), ef[i]).wrapping_add(r)
            } else {
                b.tsdf[i].wrapping_add(r)
            };
            uv[i] = u[i] as i32;
            prev = uv[i];
            ju += 1;
        }
        b.regularized = Some(u);
    }
    Ok(())
}
