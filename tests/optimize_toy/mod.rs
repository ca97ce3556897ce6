//! Analytic stand-ins for the renderer, CLIP's towers and the TF parameterization, shared by
//! the optimizer's integration tests (the real components are tested in their own modules;
//! these prove the optimizer's plumbing).
#![allow(dead_code)]

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use t2tf::image::Image;
use t2tf::optimize::driver::TextEncoder;
use t2tf::optimize::{
    Background, BoxError, ImageEncoder, Parameterization, PointGrad, Renderer, Settings, Targets,
    View,
};
use t2tf::tf::{ControlPoints, Lut, LutGrad};

pub const SIDE: usize = 6;
pub const NPIX: usize = SIDE * SIDE;
pub const LUT_N: usize = 17;
pub const K: usize = 5;
pub const D: usize = 8;
/// Extinction scale of the toy: σ = 255 on every entry gives T = exp(−KAPPA·Σ_j w_pj).
pub const KAPPA: f64 = 2.0;

/// A renderer-shaped analytic model: pixel p sees LUT entry j with weight w_pj(view) > 0;
/// T_p = exp(−κ Σ_j w_pj σ_j / 255); I_pc = (1 − T_p) Σ_j v_pj rgb_jc + T_p B_pc with
/// v = w normalized per pixel. Smooth, monotone in σ, linear in colour — like the real one.
pub struct Toy {
    pub base: Vec<Vec<f64>>,
    pub phase: Vec<Vec<f64>>,
    /// Return NaN pixels from this render call on (counts calls).
    pub nan_after: Option<usize>,
    pub calls: std::cell::Cell<usize>,
}

impl Toy {
    pub fn new(seed: u64) -> Toy {
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        let mut m = |lo: f64, hi: f64| -> Vec<Vec<f64>> {
            (0..NPIX)
                .map(|_| (0..LUT_N).map(|_| r.random_range(lo..hi)).collect())
                .collect()
        };
        let base = m(0.05, 1.0);
        let phase = m(0.0, std::f64::consts::TAU);
        Toy {
            base,
            phase,
            nan_after: None,
            calls: 0.into(),
        }
    }

    pub fn weights(&self, view: &View) -> Vec<Vec<f64>> {
        self.base
            .iter()
            .zip(&self.phase)
            .map(|(b, ph)| {
                b.iter()
                    .zip(ph)
                    .map(|(b, ph)| {
                        b * (1.0 + 0.5 * (view.yaw + ph).sin()) * (1.0 + 0.1 * view.pitch)
                            / view.distance
                            * 3.0
                    })
                    .collect()
            })
            .collect()
    }

    pub fn background(view: &View) -> Vec<f64> {
        match view.background {
            Background::Gray { level } => vec![level; NPIX * 3],
            Background::Checkerboard { seed }
            | Background::Noise { seed }
            | Background::Fourier { seed } => {
                let mut r = ChaCha8Rng::seed_from_u64(seed);
                (0..NPIX * 3).map(|_| r.random_range(0.0..1.0)).collect()
            }
        }
    }

    /// (T_p, m_pc, w, v, background), all f64.
    #[allow(clippy::type_complexity)]
    fn parts(
        &self,
        lut: &Lut,
        view: &View,
    ) -> (
        Vec<f64>,
        Vec<[f64; 3]>,
        Vec<Vec<f64>>,
        Vec<Vec<f64>>,
        Vec<f64>,
    ) {
        let w = self.weights(view);
        let mut t = Vec::with_capacity(NPIX);
        let mut m = Vec::with_capacity(NPIX);
        let mut v = Vec::with_capacity(NPIX);
        for row in &w {
            let s: f64 = row
                .iter()
                .zip(&lut.entries)
                .map(|(w, e)| w * e[0] as f64)
                .sum();
            t.push((-KAPPA * s / 255.0).exp());
            let total: f64 = row.iter().sum();
            let vr: Vec<f64> = row.iter().map(|x| x / total).collect();
            m.push(std::array::from_fn(|c| {
                vr.iter()
                    .zip(&lut.entries)
                    .map(|(v, e)| v * e[1 + c] as f64)
                    .sum()
            }));
            v.push(vr);
        }
        (t, m, w, v, Toy::background(view))
    }
}

impl Renderer for Toy {
    type Tape = ();

    fn render(&self, lut: &Lut, view: &View) -> Result<(Image, Vec<f32>, ()), BoxError> {
        let n = self.calls.get();
        self.calls.set(n + 1);
        let (t, m, _, _, bg) = self.parts(lut, view);
        let mut im = Image::new(SIDE, SIDE);
        for p in 0..NPIX {
            for c in 0..3 {
                im.data[p * 3 + c] = ((1.0 - t[p]) * m[p][c] + t[p] * bg[p * 3 + c]) as f32;
            }
        }
        if self.nan_after.is_some_and(|k| n >= k) {
            im.data[5] = f32::NAN;
        }
        Ok((im, t.iter().map(|&x| x as f32).collect(), ()))
    }

    fn backward(
        &self,
        lut: &Lut,
        view: &View,
        _tape: &(),
        d_image: &[f32],
        d_t: &[f32],
    ) -> Result<LutGrad, BoxError> {
        let (t, m, w, v, bg) = self.parts(lut, view);
        let mut g = LutGrad::zeros(LUT_N);
        for p in 0..NPIX {
            let di: [f64; 3] = std::array::from_fn(|c| d_image[p * 3 + c] as f64);
            let dt = d_t[p] as f64
                + (0..3)
                    .map(|c| di[c] * (bg[p * 3 + c] - m[p][c]))
                    .sum::<f64>();
            for j in 0..LUT_N {
                g.entries[j][0] += dt * (-t[p]) * w[p][j] * KAPPA / 255.0;
                for (c, d) in di.iter().enumerate() {
                    g.entries[j][1 + c] += d * (1.0 - t[p]) * v[p][j];
                }
            }
        }
        Ok(g)
    }
}

/// A linear "image encoder": e = M · pixels.
pub struct LinearEncoder {
    pub m: Vec<Vec<f64>>,
}

impl LinearEncoder {
    pub fn new(seed: u64) -> LinearEncoder {
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        LinearEncoder {
            m: (0..D)
                .map(|_| (0..NPIX * 3).map(|_| r.random_range(-1.0..1.0)).collect())
                .collect(),
        }
    }
}

impl ImageEncoder for LinearEncoder {
    type Cache = usize;

    fn encode(&self, images: &[Image]) -> Result<(Vec<Vec<f32>>, usize), BoxError> {
        let e = images
            .iter()
            .map(|im| {
                self.m
                    .iter()
                    .map(|row| {
                        row.iter()
                            .zip(&im.data)
                            .map(|(a, &x)| a * x as f64)
                            .sum::<f64>() as f32
                    })
                    .collect()
            })
            .collect();
        Ok((e, images.len()))
    }

    fn backward(&self, n: &usize, d: &[Vec<f32>]) -> Result<Vec<Image>, BoxError> {
        assert_eq!(*n, d.len());
        Ok(d.iter()
            .map(|de| {
                let mut im = Image::new(SIDE, SIDE);
                for (i, v) in im.data.iter_mut().enumerate() {
                    *v = self
                        .m
                        .iter()
                        .zip(de)
                        .map(|(row, &g)| row[i] * g as f64)
                        .sum::<f64>() as f32;
                }
                im
            })
            .collect())
    }

    /// Box-filter any picture of at least SIDE × SIDE down to SIDE × SIDE.
    fn prepare(&self, picture: &Image) -> Image {
        let mut out = Image::new(SIDE, SIDE);
        let (fx, fy) = (picture.width / SIDE, picture.height / SIDE);
        for y in 0..SIDE {
            for x in 0..SIDE {
                let mut acc = [0.0f32; 3];
                for dy in 0..fy {
                    for dx in 0..fx {
                        let p = picture.pixel(x * fx + dx, y * fy + dy);
                        for c in 0..3 {
                            acc[c] += p[c] / (fx * fy) as f32;
                        }
                    }
                }
                out.set_pixel(x, y, acc);
            }
        }
        out
    }
}

/// The paper's σ = 255 (tanh p + 1)/2, rgb = (tanh q + 1)/2 at K fixed, evenly spaced points
/// (positions are not optimized here; their gradient belongs to the TF module's tests).
pub struct TanhTf;

impl TanhTf {
    pub fn x() -> Vec<f64> {
        (0..K).map(|k| k as f64 / (K - 1) as f64).collect()
    }
}

impl Parameterization for TanhTf {
    fn control_points(&self, p: &[f64]) -> Result<ControlPoints, BoxError> {
        Ok(ControlPoints {
            x: TanhTf::x(),
            sigma: p[..K]
                .iter()
                .map(|p| 255.0 * (p.tanh() + 1.0) / 2.0)
                .collect(),
            rgb: (0..K)
                .map(|k| std::array::from_fn(|c| (p[K + 3 * k + c].tanh() + 1.0) / 2.0))
                .collect(),
        })
    }

    fn lut_size(&self) -> usize {
        LUT_N
    }

    fn params_for(&self, cp: &ControlPoints) -> Result<Vec<f64>, BoxError> {
        let inv = |y: f64| y.clamp(-1.0 + 1e-9, 1.0 - 1e-9).atanh();
        let mut p: Vec<f64> = cp
            .sigma
            .iter()
            .map(|s| inv(2.0 * s / 255.0 - 1.0))
            .collect();
        for c in &cp.rgb {
            p.extend(c.iter().map(|v| inv(2.0 * v - 1.0)));
        }
        Ok(p)
    }

    fn backward(&self, p: &[f64], lut: &LutGrad, direct: &PointGrad) -> Result<Vec<f64>, BoxError> {
        // LUT entry j sits at x_j = j/(n−1), between points k and k+1 with weight w.
        let x = TanhTf::x();
        let mut d_val = [[0.0f64; 4]; K];
        for (j, g) in lut.entries.iter().enumerate() {
            let t = j as f64 / (LUT_N - 1) as f64;
            let k = ((t * (K - 1) as f64) as usize).min(K - 2);
            let w = (t - x[k]) / (x[k + 1] - x[k]);
            for c in 0..4 {
                d_val[k][c] += (1.0 - w) * g[c];
                d_val[k + 1][c] += w * g[c];
            }
        }
        let mut out = vec![0.0; p.len()];
        for k in 0..K {
            let th = p[k].tanh();
            out[k] = (d_val[k][0] + direct.sigma[k]) * 255.0 / 2.0 * (1.0 - th * th);
            for c in 0..3 {
                let th = p[K + 3 * k + c].tanh();
                out[K + 3 * k + c] = (d_val[k][1 + c] + direct.rgb[k][c]) / 2.0 * (1.0 - th * th);
            }
        }
        Ok(out)
    }
}

pub struct Fixture {
    pub toy: Toy,
    pub enc: LinearEncoder,
    pub positive: Vec<f32>,
    pub pool: Vec<Vec<f32>>,
    pub user: Vec<Vec<f32>>,
}

impl Fixture {
    pub fn new() -> Fixture {
        let toy = Toy::new(1);
        let enc = LinearEncoder::new(2);
        // The positive is the embedding of a target TF's render: reachable by construction.
        let v = target_view();
        let (im, _, _) = toy.render(&target().to_lut(LUT_N), &v).unwrap();
        let positive = enc.encode(&[im]).unwrap().0.remove(0);
        // Negatives are renders too (random TFs, and a blank one as the user's "a blank
        // image"), so telling the prompt apart takes a TF close to the target.
        let mut r = ChaCha8Rng::seed_from_u64(3);
        let embed = |cp: &ControlPoints| -> Vec<f32> {
            let (im, _, _) = toy.render(&cp.to_lut(LUT_N), &v).unwrap();
            enc.encode(&[im]).unwrap().0.remove(0)
        };
        let pool = (0..40)
            .map(|_| {
                embed(&ControlPoints {
                    x: TanhTf::x(),
                    sigma: (0..K).map(|_| r.random_range(0.0..255.0)).collect(),
                    rgb: (0..K)
                        .map(|_| std::array::from_fn(|_| r.random_range(0.0..1.0)))
                        .collect(),
                })
            })
            .collect();
        let user = vec![embed(&ControlPoints {
            x: TanhTf::x(),
            sigma: vec![0.0; K],
            rgb: vec![[0.5; 3]; K],
        })];
        Fixture {
            toy,
            enc,
            positive,
            pool,
            user,
        }
    }

    pub fn targets(&self) -> Targets<'_> {
        Targets {
            positive: &self.positive,
            pool: &self.pool,
            user_negatives: &self.user,
            logit_scale: 100.0,
        }
    }
}

pub fn settings() -> Settings {
    Settings {
        steps: 80,
        views: 2,
        lr: 0.05,
        prior_start: 40,
        gray_steps: 10,
        negatives_per_step: 8,
        control_points: K,
        ..Settings::default()
    }
}

/// A histogram with one large bin (bin 0, the air around a volume) over a flat rest: what
/// the initialization and the driver tests start from.
pub fn histogram() -> Vec<u64> {
    let mut h = vec![100u64; 256];
    h[0] = 50_000;
    h
}

pub fn start_params() -> Vec<f64> {
    let cp = ControlPoints {
        x: TanhTf::x(),
        sigma: vec![60.0; K],
        rgb: vec![[0.5, 0.4, 0.6]; K],
    };
    TanhTf.params_for(&cp).unwrap()
}

/// The target TF whose render defines the positive.
pub fn target() -> ControlPoints {
    ControlPoints {
        x: TanhTf::x(),
        sigma: vec![5.0, 200.0, 20.0, 150.0, 0.0],
        rgb: vec![
            [0.9, 0.1, 0.1],
            [0.8, 0.7, 0.1],
            [0.1, 0.9, 0.2],
            [0.1, 0.2, 0.9],
            [0.5; 3],
        ],
    }
}

/// The view the target and the negatives are rendered from.
pub fn target_view() -> View {
    View {
        yaw: 0.3,
        pitch: 0.0,
        distance: 3.0,
        background: Background::Gray { level: 0.5 },
        seed: 0,
        time: 0,
    }
}

/// A text tower: known texts map to given embeddings, any other text to a pseudo-random
/// vector from its hash; empty texts are an error (as CLIP's tokenizer path makes them).
pub struct ToyText {
    pub known: Vec<(String, Vec<f32>)>,
    pub calls: std::cell::Cell<usize>,
    pub texts: std::cell::Cell<usize>,
}

impl TextEncoder for ToyText {
    fn encode_text(&self, texts: &[&str]) -> Result<Vec<Vec<f32>>, BoxError> {
        self.calls.set(self.calls.get() + 1);
        self.texts.set(self.texts.get() + texts.len());
        texts
            .iter()
            .map(|t| {
                if t.trim().is_empty() {
                    return Err("empty text".into());
                }
                if let Some((_, e)) = self.known.iter().find(|(k, _)| k == t) {
                    return Ok(e.clone());
                }
                let mut h = DefaultHasher::new();
                t.hash(&mut h);
                let mut r = ChaCha8Rng::seed_from_u64(h.finish());
                Ok((0..D).map(|_| r.random_range(-1.0f32..1.0)).collect())
            })
            .collect()
    }
}
