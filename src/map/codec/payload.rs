//! The decompressed payload of a chunk file: blocks to named byte planes and back, for both
//! layouts (`formats/chunk.md`, "Payload"): versions 1 and 2 store TSDF deltas along the coded
//! voxels, colour as is and `u − f`; version 3 stores residuals of [`predict`].

use super::predict::{cell, clamp_i16, clamp_u8, predict, predict_u, WN};
use super::{CodecError, BLOCK_DENSE, BLOCK_HAS_REGULARIZED};
use crate::grid::{Block, BlockIndex, VOXELS_PER_BLOCK};
use std::collections::HashMap;

const VB: usize = VOXELS_PER_BLOCK;

/// The blocks next to one at lower coordinates, with their coded voxels, by offset bits (bit 0:
/// x − 1, bit 1: y − 1, bit 2: z − 1; entry 0, the block itself, is `None`).
type Neighbours<'a> = [Option<(&'a Block, &'a [bool; VB])>; 8];

/// [`Neighbours`] of the block at local coordinate `l`, from `find` (local coordinate → the block
/// and its coded voxels, where the chunk holds it).
fn neighbours<'a>(
    l: [u8; 3],
    find: impl Fn([u8; 3]) -> Option<(&'a Block, &'a [bool; VB])>,
) -> Neighbours<'a> {
    std::array::from_fn(|o| {
        let d = [o & 1, (o >> 1) & 1, (o >> 2) & 1].map(|b| b as u8);
        if o == 0 || (0..3).any(|a| l[a] < d[a]) {
            return None;
        }
        find([l[0] - d[0], l[1] - d[1], l[2] - d[2]])
    })
}

/// A prediction window for one field: the block's coded voxels (values still 0: they are set as
/// the voxels are visited) and, outside the block, the neighbours' coded voxels where `get` gives
/// a value.
fn window(
    nb: &Neighbours,
    own: &[bool; VB],
    get: impl Fn(&Block, usize) -> Option<i32>,
) -> ([i32; WN], [bool; WN]) {
    let (mut v, mut c) = ([0i32; WN], [false; WN]);
    for z in -2..8i32 {
        for y in -2..8i32 {
            for x in -2..8i32 {
                let j = (x.rem_euclid(8) + 8 * y.rem_euclid(8) + 64 * z.rem_euclid(8)) as usize;
                let o = (x < 0) as usize | ((y < 0) as usize) << 1 | ((z < 0) as usize) << 2;
                let k = cell(x, y, z);
                if o == 0 {
                    c[k] = own[j];
                } else if let Some((b, m)) = nb[o] {
                    if let (true, Some(val)) = (m[j], get(b, j)) {
                        v[k] = val;
                        c[k] = true;
                    }
                }
            }
        }
    }
    (v, c)
}

/// Window cell of voxel `i` of the block.
#[inline]
fn cell_of(i: usize) -> usize {
    cell((i % 8) as i32, ((i / 8) % 8) as i32, (i / 64) as i32)
}

fn tsdf_of(b: &Block, j: usize) -> Option<i32> {
    Some(b.tsdf[j] as i32)
}

fn u_of(b: &Block, j: usize) -> Option<i32> {
    b.regularized.as_ref().map(|u| u[j] as i32)
}

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
    let masks: Vec<[bool; VB]> = order
        .iter()
        .zip(&flags)
        .map(|((_, b), f)| coded_mask(&b.weight_omega, f & BLOCK_DENSE != 0))
        .collect();
    let by_place: HashMap<[u8; 3], usize> = order
        .iter()
        .enumerate()
        .map(|(k, (l, _))| (*l, k))
        .collect();
    for ((l, b), coded) in order.iter().zip(&masks) {
        if predicted {
            let nb = neighbours(*l, |p| by_place.get(&p).map(|&q| (order[q].1, &masks[q])));
            residuals_v3(b, coded, &nb, &mut tsdf, &mut rgb, &mut reg);
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
    nb: &Neighbours,
    tsdf: &mut Vec<u16>,
    rgb: &mut [Vec<u8>; 3],
    reg: &mut Vec<u16>,
) {
    let (mut f, fc) = window(nb, coded, tsdf_of);
    let mut ef = [0i32; VB];
    let mut prev = 0;
    for i in (0..VB).filter(|&i| coded[i]) {
        let p = clamp_i16(predict(&f, &fc, i, prev));
        tsdf.push(zigzag(b.tsdf[i].wrapping_sub(p)));
        ef[i] = b.tsdf[i] as i32 - p as i32;
        f[cell_of(i)] = b.tsdf[i] as i32;
        prev = b.tsdf[i] as i32;
    }
    // Each channel's residual, stored less the previous channel's (0 for grey voxels).
    let mut before = [0u8; VB];
    for (ch, plane) in rgb.iter_mut().enumerate() {
        let (mut c, cc) = window(nb, coded, |b, j| Some(b.color[j][ch] as i32));
        let mut prev = 0;
        for i in (0..VB).filter(|&i| coded[i]) {
            let r = b.color[i][ch].wrapping_sub(clamp_u8(predict(&c, &cc, i, prev)));
            plane.push(r.wrapping_sub(before[i]));
            before[i] = r;
            c[cell_of(i)] = b.color[i][ch] as i32;
            prev = b.color[i][ch] as i32;
        }
    }
    if let Some(u) = &b.regularized {
        let (mut uv, uc) = window(nb, coded, u_of);
        let mut prev = 0;
        for i in (0..VB).filter(|&i| coded[i]) {
            let p = predict_u(clamp_i16(predict(&uv, &uc, i, prev)), ef[i]);
            reg.push(zigzag(u[i].wrapping_sub(p)));
            uv[cell_of(i)] = u[i] as i32;
            prev = u[i] as i32;
        }
    }
}

/// Reads the voxel planes (TSDF, colour, `u`: `rest`, the payload after the weights) into
/// `blocks`, whose weights are set; `flags` are the block flags, `k` and `k_reg` the coded voxels
/// in all blocks and in those with `u`.
pub fn read_voxel_planes(
    blocks: &mut [(BlockIndex, Box<Block>)],
    locals: &[[u8; 3]],
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
    let masks: Vec<[bool; VB]> = blocks
        .iter()
        .zip(flags)
        .map(|((_, b), f)| coded_mask(&b.weight_omega, f & BLOCK_DENSE != 0))
        .collect();
    let by_place: HashMap<[u8; 3], usize> =
        locals.iter().enumerate().map(|(k, l)| (*l, k)).collect();
    for k in 0..blocks.len() {
        // Blocks before `k` are decoded; its neighbours at lower coordinates are among them.
        let (done, rest) = blocks.split_at_mut(k);
        let b = &mut *rest[0].1;
        let (f, coded) = (flags[k], &masks[k]);
        let nb = neighbours(locals[k], |p| {
            by_place
                .get(&p)
                .filter(|&&q| q < k)
                .map(|&q| (&*done[q].1, &masks[q]))
        });
        let j0 = j;
        let (mut fv, fc) = window(&nb, coded, tsdf_of);
        let mut ef = [0i32; VB];
        let mut prev = 0i32;
        for i in (0..VB).filter(|&i| coded[i]) {
            let r = word(tlo, thi, j);
            b.tsdf[i] = if predicted {
                let p = clamp_i16(predict(&fv, &fc, i, prev));
                let t = p.wrapping_add(r);
                ef[i] = t as i32 - p as i32;
                t
            } else {
                (prev as i16).wrapping_add(r)
            };
            fv[cell_of(i)] = b.tsdf[i] as i32;
            prev = b.tsdf[i] as i32;
            j += 1;
        }
        let mut before = [0u8; VB];
        for (ch, plane) in planes.iter().enumerate() {
            let (mut c, cc) = window(&nb, coded, |b, j| Some(b.color[j][ch] as i32));
            let mut prev = 0i32;
            for (jj, i) in (j0..).zip((0..VB).filter(|&i| coded[i])) {
                b.color[i][ch] = if predicted {
                    let r = plane[jj].wrapping_add(before[i]);
                    before[i] = r;
                    r.wrapping_add(clamp_u8(predict(&c, &cc, i, prev)))
                } else {
                    plane[jj]
                };
                c[cell_of(i)] = b.color[i][ch] as i32;
                prev = b.color[i][ch] as i32;
            }
        }
        if f & BLOCK_HAS_REGULARIZED == 0 {
            continue;
        }
        let mut u = Box::new(b.tsdf);
        let (mut uv, uc) = window(&nb, coded, u_of);
        let mut prev = 0i32;
        for i in (0..VB).filter(|&i| coded[i]) {
            let r = word(ulo, uhi, ju);
            u[i] = if predicted {
                predict_u(clamp_i16(predict(&uv, &uc, i, prev)), ef[i]).wrapping_add(r)
            } else {
                b.tsdf[i].wrapping_add(r)
            };
            uv[cell_of(i)] = u[i] as i32;
            prev = u[i] as i32;
            ju += 1;
        }
        b.regularized = Some(u);
    }
    Ok(())
}
