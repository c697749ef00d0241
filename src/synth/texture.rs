//! Procedural textures of the synthetic city: value noise and fractal sums of it, and the albedo
//! patterns (asphalt, paving slabs, bricks, plaster, concrete panels, windows, foliage, bark,
//! paint) evaluated at exact surface points. Deterministic (hash-based), no image files. Colours
//! are linear RGB albedo in [0, 1]. Does not shade (no lights) and does not know the city layout.

use super::rng::{hash3, mix64, unit};

/// Linear RGB albedo.
pub type Rgb = [f32; 3];

#[inline]
fn lattice3(x: i64, y: i64, z: i64, seed: u64) -> f64 {
    unit(mix64(
        seed ^ (x as u64).wrapping_mul(0x8CB9_2BA7_2F3D_8DD7)
            ^ (y as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93)
            ^ (z as u64).wrapping_mul(0xA076_1D64_78BD_642F),
    ))
}

#[inline]
fn smooth(t: f64) -> f64 {
    t * t * (3.0 - 2.0 * t)
}

/// Value noise in [0, 1) at `p` (lattice spacing 1), trilinear with smoothstep weights.
pub fn value_noise3(p: [f64; 3], seed: u64) -> f64 {
    let (fx, fy, fz) = (p[0].floor(), p[1].floor(), p[2].floor());
    let (x, y, z) = (fx as i64, fy as i64, fz as i64);
    let (tx, ty, tz) = (smooth(p[0] - fx), smooth(p[1] - fy), smooth(p[2] - fz));
    let mut acc = 0.0;
    for dz in 0..2 {
        let wz = if dz == 0 { 1.0 - tz } else { tz };
        for dy in 0..2 {
            let wy = if dy == 0 { 1.0 - ty } else { ty };
            let wyz = wy * wz;
            let a = lattice3(x, y + dy, z + dz, seed);
            let b = lattice3(x + 1, y + dy, z + dz, seed);
            acc += wyz * (a + (b - a) * tx);
        }
    }
    acc
}

/// Fractal sum of `octaves` value-noise octaves at `p · frequency`, normalised to [0, 1).
pub fn fbm3(p: [f64; 3], frequency: f64, octaves: u32, seed: u64) -> f64 {
    let (mut amp, mut f, mut sum, mut norm) = (1.0, frequency, 0.0, 0.0);
    for o in 0..octaves {
        sum += amp
            * value_noise3(
                [p[0] * f, p[1] * f, p[2] * f],
                seed.wrapping_add(o as u64 * 0x9E37),
            );
        norm += amp;
        amp *= 0.5;
        f *= 2.03;
    }
    sum / norm
}

/// A per-cell random number in [0, 1) for integer cell `(i, j)`.
#[inline]
pub fn cell_random(i: i64, j: i64, seed: u64) -> f64 {
    unit(hash3(seed, i as u64, j as u64))
}

#[inline]
pub(crate) fn scale(c: Rgb, k: f64) -> Rgb {
    [
        (c[0] as f64 * k) as f32,
        (c[1] as f64 * k) as f32,
        (c[2] as f64 * k) as f32,
    ]
}

#[inline]
pub(crate) fn mix(a: Rgb, b: Rgb, t: f64) -> Rgb {
    let t = t.clamp(0.0, 1.0) as f32;
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

/// Wall finishes of a facade.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WallStyle {
    /// Running-bond bricks with mortar joints (strong texture).
    Brick,
    /// Smooth plaster with faint low-frequency variation (texture-poor).
    Plaster,
    /// Precast concrete panels with joints.
    Panel,
}

/// Everything the facade texture needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FacadeParams {
    /// Wall colour (linear RGB).
    pub wall: Rgb,
    /// Wall finish.
    pub style: WallStyle,
    /// Storey height, metres.
    pub floor_height_m: f64,
    /// Window bay width (window + pier), metres.
    pub bay_width_m: f64,
    /// Window width, metres.
    pub window_width_m: f64,
    /// Window height, metres.
    pub window_height_m: f64,
    /// Ground height at the building (world y of the ground; y points down), metres.
    pub ground_y_m: f64,
    /// Whether the short sides carry windows (otherwise they are blank walls).
    pub side_windows: bool,
    /// Whether the ground floor is a shop front (large glazing).
    pub shop: bool,
    /// Texture seed.
    pub seed: u64,
}

/// Albedo of a facade at horizontal position `u_m` along a face of width `face_width_m` and
/// height `h_m` above the ground; `windows` says whether this face has windows.
pub fn facade(
    f: &FacadeParams,
    u_m: f64,
    face_width_m: f64,
    h_m: f64,
    windows: bool,
    face_id: u64,
    world: [f64; 3],
) -> Rgb {
    let seed = f.seed ^ face_id.wrapping_mul(0x2545_F491_4F6C_DD1D);
    let grime = fbm3(world, 0.35, 3, seed ^ 11);
    let wall = wall_albedo(f, u_m, h_m, world);
    // Darker plinth and a stain gradient near the ground.
    let wall = if h_m < 0.6 {
        scale(wall, 0.7)
    } else {
        scale(wall, 0.85 + 0.3 * grime - 0.1 * (-(h_m - 0.6) / 2.0).exp())
    };
    if !windows {
        return wall;
    }
    let floor = (h_m / f.floor_height_m).floor();
    let fh = h_m - floor * f.floor_height_m;
    let n_bays = (face_width_m / f.bay_width_m).floor().max(0.0);
    if n_bays < 1.0 {
        return wall;
    }
    let margin = 0.5 * (face_width_m - n_bays * f.bay_width_m);
    let ub = u_m - margin;
    if ub < 0.0 || ub >= n_bays * f.bay_width_m {
        return wall;
    }
    let bay = (ub / f.bay_width_m).floor();
    let bu = ub - bay * f.bay_width_m - 0.5 * f.bay_width_m;
    // Storey band (string course) under each floor line on plaster and panel walls.
    if f.style != WallStyle::Brick && fh < 0.18 && floor >= 1.0 {
        return scale(wall, 0.8);
    }
    let (half_w, sill, top) = if floor == 0.0 && f.shop {
        (0.5 * f.bay_width_m - 0.25, 0.45, f.floor_height_m - 0.35)
    } else if floor == 0.0 {
        (
            0.5 * f.window_width_m,
            1.1,
            1.1 + f.window_height_m.min(f.floor_height_m - 1.4),
        )
    } else {
        (
            0.5 * f.window_width_m,
            0.9,
            0.9 + f.window_height_m.min(f.floor_height_m - 1.1),
        )
    };
    let frame = 0.07;
    let in_x = bu.abs() < half_w;
    let in_y = fh > sill && fh < top;
    if in_x && in_y {
        if bu.abs() > half_w - frame || fh < sill + frame || fh > top - frame {
            return [0.75, 0.74, 0.7];
        }
        // Glazing bars.
        if (bu.abs() < 0.03 && half_w > 0.5) || ((fh - sill) - 0.62 * (top - sill)).abs() < 0.03 {
            return [0.7, 0.69, 0.66];
        }
        let r = cell_random(bay as i64, floor as i64, seed ^ 0x77);
        // Sky reflection gradient + curtains or lit rooms in some windows.
        let t = (fh - sill) / (top - sill);
        let glass = mix([0.05, 0.07, 0.1], [0.22, 0.27, 0.33], t * 0.8 + 0.2 * r);
        if r > 0.75 {
            let curtain = 0.5 + 0.5 * (bu * 14.0).sin();
            return mix(glass, [0.55, 0.5, 0.42], 0.6 * curtain);
        }
        return glass;
    }
    // Sills under the windows.
    if in_x && fh <= sill && fh > sill - 0.12 && !(floor == 0.0 && f.shop) {
        return [0.6, 0.6, 0.58];
    }
    wall
}

fn wall_albedo(f: &FacadeParams, u_m: f64, h_m: f64, world: [f64; 3]) -> Rgb {
    match f.style {
        WallStyle::Brick => {
            let course = (h_m / 0.075).floor();
            let offset = if (course as i64) % 2 == 0 { 0.0 } else { 0.12 };
            let bu = (u_m + offset) / 0.24;
            let brick = bu.floor();
            let fu = bu - brick;
            let fv = h_m / 0.075 - course;
            if fu < 0.05 || fv < 0.14 {
                return [0.55, 0.53, 0.5];
            }
            let r = cell_random(brick as i64, course as i64, f.seed);
            scale(f.wall, 0.75 + 0.45 * r)
        }
        WallStyle::Plaster => {
            let n = fbm3(world, 0.8, 2, f.seed ^ 3);
            scale(f.wall, 0.95 + 0.08 * n)
        }
        WallStyle::Panel => {
            let pu = u_m / 1.8;
            let pv = h_m / (f.floor_height_m * 0.5);
            if pu - pu.floor() < 0.012 || pv - pv.floor() < 0.02 {
                return scale(f.wall, 0.55);
            }
            let r = cell_random(pu.floor() as i64, pv.floor() as i64, f.seed ^ 5);
            let speck = fbm3(world, 6.0, 2, f.seed ^ 9);
            scale(f.wall, 0.85 + 0.15 * r + 0.15 * speck)
        }
    }
}

/// Asphalt: dark grey with aggregate speckle, mid-scale mottling and patches.
pub fn asphalt(world: [f64; 3], seed: u64) -> Rgb {
    let patch = fbm3(world, 0.15, 3, seed ^ 21);
    let mottle = value_noise3([world[0] * 2.5, world[1] * 2.5, world[2] * 2.5], seed ^ 24);
    let grain = value_noise3(
        [world[0] * 40.0, world[1] * 40.0, world[2] * 40.0],
        seed ^ 22,
    );
    let fine = value_noise3([world[0] * 9.0, world[1] * 9.0, world[2] * 9.0], seed ^ 23);
    let g = 0.05 + 0.07 * patch + 0.05 * mottle + 0.06 * grain + 0.05 * fine;
    [g as f32, g as f32, (g * 1.04) as f32]
}

/// Paving slabs in street coordinates (`s_m` along, `l_m` across).
pub fn paving(s_m: f64, l_m: f64, world: [f64; 3], seed: u64) -> Rgb {
    let (a, b) = (s_m / 0.6, l_m / 0.6);
    let (fa, fb) = (a - a.floor(), b - b.floor());
    if fa < 0.03 || fb < 0.03 {
        return [0.2, 0.2, 0.19];
    }
    let r = cell_random(a.floor() as i64, b.floor() as i64, seed ^ 31);
    let n = fbm3(world, 3.0, 2, seed ^ 32);
    let g = 0.32 + 0.08 * r + 0.08 * n;
    [g as f32, (g * 0.98) as f32, (g * 0.94) as f32]
}

/// Grass and soil between buildings.
pub fn verge(world: [f64; 3], seed: u64) -> Rgb {
    let n = fbm3(world, 0.5, 3, seed ^ 41);
    let fine = value_noise3(
        [world[0] * 25.0, world[1] * 25.0, world[2] * 25.0],
        seed ^ 42,
    );
    let grass = [0.08 + 0.05 * fine as f32, 0.16 + 0.08 * fine as f32, 0.05];
    mix(grass, [0.2, 0.16, 0.11], (n - 0.35) * 2.5)
}

/// Tree foliage: clumpy greens with dark gaps between leaf clusters.
pub fn foliage(world: [f64; 3], base: Rgb, seed: u64) -> Rgb {
    let clump = fbm3(world, 2.5, 3, seed);
    let leaf = value_noise3(
        [world[0] * 14.0, world[1] * 14.0, world[2] * 14.0],
        seed ^ 51,
    );
    let k = (0.6 + 2.2 * (clump - 0.5)).clamp(0.15, 1.6)
        * if leaf < 0.3 { 0.35 } else { 0.7 + 0.6 * leaf };
    scale(base, k)
}

/// Bark, roofs and other rough surfaces: `base` modulated by noise of `frequency` cycles per metre.
pub fn rough(world: [f64; 3], base: Rgb, frequency: f64, amount: f64, seed: u64) -> Rgb {
    let n = fbm3(world, frequency, 3, seed);
    scale(base, 1.0 - amount + 2.0 * amount * n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_bounded_continuous_and_deterministic() {
        let mut prev = value_noise3([0.0, 0.3, 0.7], 5);
        for i in 1..2000 {
            let x = i as f64 * 0.001;
            let v = value_noise3([x, 0.3, 0.7], 5);
            assert!((0.0..1.0).contains(&v));
            assert!((v - prev).abs() < 0.01, "jump at {x}");
            prev = v;
        }
        assert_eq!(
            fbm3([1.5, 2.5, 3.5], 1.0, 4, 9),
            fbm3([1.5, 2.5, 3.5], 1.0, 4, 9)
        );
        assert_ne!(
            fbm3([1.5, 2.5, 3.5], 1.0, 4, 9),
            fbm3([1.5, 2.5, 3.5], 1.0, 4, 10)
        );
    }

    #[test]
    fn windows_are_darker_than_plaster_walls() {
        let f = FacadeParams {
            wall: [0.6, 0.55, 0.45],
            style: WallStyle::Plaster,
            floor_height_m: 3.2,
            bay_width_m: 3.0,
            window_width_m: 1.4,
            window_height_m: 1.5,
            ground_y_m: 1.65,
            side_windows: false,
            shop: false,
            seed: 1,
        };
        // Face 9 m wide: three bays, the middle window centred at u = 4.5 m, on floor 1 at h = 4.9 m.
        let glass = facade(&f, 4.5 + 0.3, 9.0, 3.2 + 1.5, true, 0, [0.0; 3]);
        let wall = facade(&f, 3.05, 9.0, 3.2 + 1.5, true, 0, [0.0; 3]);
        assert!(
            glass[0] < 0.35 && wall[0] > 0.45,
            "glass {glass:?} wall {wall:?}"
        );
    }
}
