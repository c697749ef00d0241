//! The TGV operators: the anisotropic diffusion tensors of the image, forward-difference
//! gradient and divergence, the symmetrised gradient and its divergence (see [`super`]).

#[allow(unused_imports)]
use super::*;

/// Per-pixel diffusion tensor `T` as `[t11, t12, t22]` (symmetric, eigenvalues in (0, 1]).
pub type Tensor = [f32; 3];

/// The tensors of `image`: `T = exp(−γ|∇I|^β) n nᵀ + n⊥ n⊥ᵀ` with `I` in [0, 1] and central
/// differences (one-sided at the border). With `γ = 0` every tensor is the identity.
pub fn diffusion_tensors(image: &GreyImage, gamma: f32, beta: f32) -> Vec<Tensor> {
    let w = image.width as usize;
    let h = image.height as usize;
    let at = |x: usize, y: usize| image.data[y * w + x] as f32 / 255.0;
    let mut out = vec![[1.0, 0.0, 1.0]; w * h];
    if w == 0 {
        return out;
    }
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, t) in row.iter_mut().enumerate() {
            let (xl, xr) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let (yu, yd) = (y.saturating_sub(1), (y + 1).min(h - 1));
            let gx = if xr > xl {
                (at(xr, y) - at(xl, y)) / (xr - xl) as f32
            } else {
                0.0
            };
            let gy = if yd > yu {
                (at(x, yd) - at(x, yu)) / (yd - yu) as f32
            } else {
                0.0
            };
            let norm = (gx * gx + gy * gy).sqrt();
            if norm < 1e-6 {
                continue;
            }
            let (n1, n2) = (gx / norm, gy / norm);
            let k = 1.0 - (-gamma * norm.powf(beta)).exp();
            *t = [1.0 - k * n1 * n1, -k * n1 * n2, 1.0 - k * n2 * n2];
        }
    });
    out
}

/// Forward-difference gradient with Neumann boundary of the scalar field `u` (`w × h`):
/// `[u(x+1) − u(x), u(y+1) − u(y)]`, 0 across the last column/row.
pub fn gradient(u: &[f32], w: usize, h: usize) -> Vec<[f32; 2]> {
    let mut g = vec![[0.0; 2]; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let gx = if x + 1 < w { u[i + 1] - u[i] } else { 0.0 };
            let gy = if y + 1 < h { u[i + w] - u[i] } else { 0.0 };
            g[i] = [gx, gy];
        }
    }
    g
}

/// `div p = −∇ᵀp` for [`gradient`].
pub fn divergence(p: &[[f32; 2]], w: usize, h: usize) -> Vec<f32> {
    let mut d = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            d[y * w + x] = div_at(|i| p[i], w, h, x, y);
        }
    }
    d
}

#[inline(always)]
pub(super) fn div_at(p: impl Fn(usize) -> [f32; 2], w: usize, h: usize, x: usize, y: usize) -> f32 {
    let i = y * w + x;
    let mut d = 0.0;
    if x + 1 < w {
        d += p(i)[0];
    }
    if x > 0 {
        d -= p(i - 1)[0];
    }
    if y + 1 < h {
        d += p(i)[1];
    }
    if y > 0 {
        d -= p(i - w)[1];
    }
    d
}

/// Symmetrised gradient `ε(v)` of the vector field `v` with backward differences (0 across the
/// first column/row), as `[ε11, ε22, ε12]`.
pub fn sym_gradient(v: &[[f32; 2]], w: usize, h: usize) -> Vec<[f32; 3]> {
    let mut e = vec![[0.0; 3]; w * h];
    for y in 0..h {
        for x in 0..w {
            e[y * w + x] = sym_grad_at(|i| v[i], w, x, y);
        }
    }
    e
}

#[inline(always)]
pub(super) fn sym_grad_at(v: impl Fn(usize) -> [f32; 2], w: usize, x: usize, y: usize) -> [f32; 3] {
    let i = y * w + x;
    let c = v(i);
    let (l, u) = (
        if x > 0 { v(i - 1) } else { c },
        if y > 0 { v(i - w) } else { c },
    );
    [
        c[0] - l[0],
        c[1] - u[1],
        0.5 * ((c[0] - u[0]) + (c[1] - l[1])),
    ]
}

/// `div_sym q = −εᵀq` for [`sym_gradient`], with the inner product
/// `⟨a, b⟩ = a11·b11 + a22·b22 + 2·a12·b12`.
pub fn sym_divergence(q: &[[f32; 3]], w: usize, h: usize) -> Vec<[f32; 2]> {
    let mut d = vec![[0.0; 2]; w * h];
    for y in 0..h {
        for x in 0..w {
            d[y * w + x] = sym_div_at(|i| q[i], w, h, x, y);
        }
    }
    d
}

#[inline(always)]
pub(super) fn sym_div_at(
    q: impl Fn(usize) -> [f32; 3],
    w: usize,
    h: usize,
    x: usize,
    y: usize,
) -> [f32; 2] {
    let i = y * w + x;
    let c = q(i);
    let (mut d1, mut d2) = (0.0, 0.0);
    if x > 0 {
        d1 += c[0];
        d2 += c[2];
    }
    if x + 1 < w {
        let r = q(i + 1);
        d1 -= r[0];
        d2 -= r[2];
    }
    if y > 0 {
        d1 += c[2];
        d2 += c[1];
    }
    if y + 1 < h {
        let b = q(i + w);
        d1 -= b[2];
        d2 -= b[1];
    }
    [-d1, -d2]
}

#[inline(always)]
pub(super) fn apply(t: Tensor, g: [f32; 2]) -> [f32; 2] {
    [t[0] * g[0] + t[1] * g[1], t[1] * g[0] + t[2] * g[1]]
}
