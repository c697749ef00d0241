//! Binary glTF 2.0 (GLB) for one coloured triangle mesh: what each 3D Tiles tile holds.
//! Byte layout: `formats/3dtiles.md`.
//!
//! What it does: writes positions (`f32`, with the accessor bounds glTF requires), vertex colours
//! as `COLOR_0` (sRGB input converted to the linear `u16` values glTF asks for, RGBA with alpha 1)
//! and `u32` (or `u16`) triangle indices, with an unlit material (`KHR_materials_unlit`) so the
//! fused colours show as they were observed. Positions are taken as glTF's y-up coordinates.
//!
//! What it does not do: normals, textures, compression (Draco, meshopt), or reading GLB back
//! beyond [`parse_glb`] (the JSON chunk and the binary chunk, for tests).

use crate::error::{Error, Result};

/// glTF `COLOR_0` values are linear; fused colours are sRGB bytes.
fn srgb_to_linear_u16(c: u8) -> u16 {
    let s = c as f64 / 255.0;
    let l = if s <= 0.04045 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    };
    (l * 65535.0).round() as u16
}

fn pad4(v: &mut Vec<u8>, byte: u8) {
    while !v.len().is_multiple_of(4) {
        v.push(byte);
    }
}

/// Encodes one mesh as GLB: `positions` (glTF frame, y up, metres), `colors_srgb` (one per
/// position) and `triangles` (counter-clockwise seen from outside). Fails on mismatched lengths
/// or out-of-range indices.
pub fn encode_glb(
    positions: &[[f32; 3]],
    colors_srgb: &[[u8; 3]],
    triangles: &[[u32; 3]],
) -> Result<Vec<u8>> {
    let n = positions.len();
    if colors_srgb.len() != n {
        return Err(Error::InvalidArgument(format!(
            "GLB: {n} positions but {} colours",
            colors_srgb.len()
        )));
    }
    if triangles.iter().flatten().any(|&i| i as usize >= n) {
        return Err(Error::InvalidArgument(
            "GLB: a triangle index exceeds the vertex count".into(),
        ));
    }
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    let mut bin = Vec::with_capacity(n * 20 + triangles.len() * 12);
    for p in positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
            bin.extend_from_slice(&p[a].to_le_bytes());
        }
    }
    let pos_len = bin.len();
    let lut: Vec<u16> = (0..=255u8).map(srgb_to_linear_u16).collect();
    for c in colors_srgb {
        for &v in c {
            bin.extend_from_slice(&lut[v as usize].to_le_bytes());
        }
        bin.extend_from_slice(&u16::MAX.to_le_bytes());
    }
    let col_len = bin.len() - pos_len;
    let short = n <= u16::MAX as usize;
    for t in triangles {
        for &i in t {
            if short {
                bin.extend_from_slice(&(i as u16).to_le_bytes());
            } else {
                bin.extend_from_slice(&i.to_le_bytes());
            }
        }
    }
    let idx_len = bin.len() - pos_len - col_len;
    pad4(&mut bin, 0);
    let json = serde_json::json!({
        "asset": {"version": "2.0", "generator": format!("denser {}", env!("CARGO_PKG_VERSION"))},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "COLOR_0": 1},
            "indices": 2,
            "material": 0,
            "mode": 4
        }]}],
        "materials": [{
            "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "doubleSided": true,
            "extensions": {"KHR_materials_unlit": {}}
        }],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3",
             "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5123, "normalized": true, "count": n, "type": "VEC4"},
            {"bufferView": 2, "componentType": if short { 5123 } else { 5125 },
             "count": triangles.len() * 3, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos_len, "target": 34962},
            {"buffer": 0, "byteOffset": pos_len, "byteLength": col_len, "target": 34962},
            {"buffer": 0, "byteOffset": pos_len + col_len, "byteLength": idx_len, "target": 34963}
        ],
        "buffers": [{"byteLength": bin.len()}]
    });
    let mut json =
        serde_json::to_vec(&json).map_err(|e| Error::InvalidArgument(format!("GLB JSON: {e}")))?;
    pad4(&mut json, b' ');
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    Ok(out)
}

/// Splits a GLB into its JSON and binary chunks (checks magic, version and lengths).
pub fn parse_glb(bytes: &[u8]) -> std::result::Result<(serde_json::Value, &[u8]), String> {
    let u32_at = |o: usize| -> std::result::Result<u32, String> {
        bytes
            .get(o..o + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| "truncated GLB".to_string())
    };
    if bytes.get(..4) != Some(b"glTF") || u32_at(4)? != 2 {
        return Err("not a glTF 2.0 binary (magic 'glTF', version 2)".into());
    }
    if u32_at(8)? as usize != bytes.len() {
        return Err(format!(
            "GLB length {} but the file has {} bytes",
            u32_at(8)?,
            bytes.len()
        ));
    }
    let jl = u32_at(12)? as usize;
    if bytes.get(16..20) != Some(b"JSON") {
        return Err("first GLB chunk is not JSON".into());
    }
    let json: serde_json::Value = serde_json::from_slice(
        bytes
            .get(20..20 + jl)
            .ok_or_else(|| "truncated JSON chunk".to_string())?,
    )
    .map_err(|e| format!("GLB JSON: {e}"))?;
    let bl = u32_at(20 + jl)? as usize;
    if bytes.get(24 + jl..28 + jl) != Some(b"BIN\0") {
        return Err("second GLB chunk is not BIN".into());
    }
    let bin = bytes
        .get(28 + jl..28 + jl + bl)
        .ok_or_else(|| "truncated BIN chunk".to_string())?;
    Ok((json, bin))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glb_round_trip_of_a_triangle() {
        let glb = encode_glb(
            &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            &[[255, 0, 0], [0, 128, 0], [0, 0, 0]],
            &[[0, 1, 2]],
        )
        .unwrap();
        assert_eq!(glb.len() % 4, 0);
        let (json, bin) = parse_glb(&glb).unwrap();
        assert_eq!(json["accessors"][0]["count"], 3);
        assert_eq!(json["accessors"][0]["max"][0], 1.0);
        // 36 bytes of positions, 24 of colours, 6 of indices padded to 8.
        assert_eq!(bin.len(), 36 + 24 + 8);
        assert_eq!(&bin[36..38], &u16::MAX.to_le_bytes()); // red 255 → linear 1.0
                                                           // sRGB 128 → linear 0.2158605.
        let g = u16::from_le_bytes([bin[44 + 2], bin[44 + 3]]) as f64 / 65535.0;
        assert!((g - 0.2158605).abs() < 1e-4, "{g}");
        assert!(parse_glb(&glb[..glb.len() - 4]).is_err());
    }
}
