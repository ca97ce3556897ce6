//! The per-step plan of Algorithm 1: views, backgrounds, negatives, prior on/off and learning
//! rate, all drawn from a seeded RNG.
//!
//! Each step has its own random stream (ChaCha8 seeded with the run's seed, stream = step
//! index), so step i's plan depends only on (seed, i, settings) and not on how many steps ran
//! before it or whether the run was interrupted: same seed ⇒ same plan.

pub use crate::background::Background;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::captions::sample_indices;
use super::settings::Settings;
use super::sgd::linear_lr;

/// One camera and its background. Angles in radians; the camera orbits the volume centre.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct View {
    /// In [0, 2π).
    pub yaw: f64,
    /// In [−pitch_limit, pitch_limit].
    pub pitch: f64,
    /// Distance from the volume centre in bounding radii (multiply by
    /// `Geometry::bounding_radius()` for world units).
    pub distance: f64,
    /// What the rays that leave the volume show.
    pub background: Background,
    /// Seed for any randomness of the renderer in this view (e.g. per-ray sample jitter;
    /// forward and backward of the view must use the same one).
    pub seed: u64,
    /// The time step rendered (an index into the renderer's steps; 0 for one volume).
    #[serde(default)]
    pub time: usize,
}

impl View {
    /// The fixed view V0 of the initialization: front (yaw 0, pitch 0) at the middle of the
    /// distance range, on mid gray (the background does not affect T_N).
    pub fn initial(settings: &Settings) -> View {
        View {
            yaw: 0.0,
            pitch: 0.0,
            distance: 0.5 * (settings.distance[0] + settings.distance[1]),
            background: Background::Gray { level: 0.5 },
            seed: 0,
            time: 0,
        }
    }

    /// `n` views evenly spaced in yaw at pitch 0 and mid distance on white: for preview.png
    /// and the final CLIP scores (fixed, so runs are comparable).
    pub fn orbit(settings: &Settings, n: usize) -> Vec<View> {
        (0..n)
            .map(|i| View {
                yaw: std::f64::consts::TAU * i as f64 / n.max(1) as f64,
                pitch: 0.0,
                distance: 0.5 * (settings.distance[0] + settings.distance[1]),
                background: Background::Gray { level: 1.0 },
                seed: 0,
                time: 0,
            })
            .collect()
    }
}

/// Everything random about one step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepPlan {
    /// 0-based step index.
    pub step: usize,
    /// Learning rate of this step (linear annealing).
    pub lr: f64,
    /// The views rendered this step.
    pub views: Vec<View>,
    /// Indices into the caption pool (distinct).
    pub negatives: Vec<usize>,
    /// Whether the Beta prior is on.
    pub prior: bool,
}

/// The plan of step `step` for a pool of `pool_size` captions.
pub fn plan(settings: &Settings, pool_size: usize, step: usize) -> StepPlan {
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    rng.set_stream(step as u64);
    let views = (0..settings.views)
        .map(|_| {
            let yaw = rng.random_range(0.0..std::f64::consts::TAU);
            let pitch = if settings.pitch_limit > 0.0 {
                rng.random_range(-settings.pitch_limit..=settings.pitch_limit)
            } else {
                0.0
            };
            let [d0, d1] = settings.distance;
            let distance = if d1 > d0 {
                rng.random_range(d0..=d1)
            } else {
                d0
            };
            let background = if step < settings.gray_steps {
                Background::Gray {
                    level: rng.random_range(0.0..=1.0),
                }
            } else {
                let seed = rng.random();
                match rng.random_range(0..3) {
                    0 => Background::Checkerboard { seed },
                    1 => Background::Noise { seed },
                    _ => Background::Fourier { seed },
                }
            };
            View {
                yaw,
                pitch,
                distance,
                background,
                seed: rng.random(),
                time: 0,
            }
        })
        .collect();
    let negatives = sample_indices(pool_size, settings.negatives_per_step, &mut rng);
    StepPlan {
        step,
        lr: linear_lr(settings.lr, step, settings.steps),
        views,
        negatives,
        prior: step >= settings.prior_start,
    }
}

/// Give the views of `plan` time steps of a series of `count` (nothing changes for one).
///
/// The views of step s take entries s, s + 1, … of one sequence that visits every time step
/// once per round, in a seeded random order per round (stratified: over `count` consecutive
/// entries each step appears once). Consecutive steps thus share all views' time steps but
/// one, so a run loads about one new time step per step however long the series is, while
/// every step's gradient still mixes several times and the run covers all of them evenly.
pub fn assign_times(plan: &mut StepPlan, count: usize, seed: u64) {
    if count <= 1 {
        return;
    }
    for (v, view) in plan.views.iter_mut().enumerate() {
        view.time = time_order(plan.step + v, count, seed);
    }
}

/// Entry `j` of the sequence [`assign_times`] draws from: round `j / count` is a
/// permutation of the time steps drawn from its own random stream.
pub fn time_order(j: usize, count: usize, seed: u64) -> usize {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7469_6d65_7374_6570);
    rng.set_stream((j / count) as u64);
    let mut order: Vec<usize> = (0..count).collect();
    for i in (1..count).rev() {
        order.swap(i, rng.random_range(0..=i));
    }
    order[j % count]
}

/// The time steps preview.png shows: the first, the middle and the last (fewer when the
/// series is shorter).
pub fn preview_times(count: usize) -> Vec<usize> {
    let mut t = vec![0, count / 2, count.saturating_sub(1)];
    t.dedup();
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn same_seed_same_plan_other_seed_other_plan() {
        let s = Settings::default();
        for step in [0, 24, 25, 99, 100, 299] {
            assert_eq!(plan(&s, 6000, step), plan(&s, 6000, step));
        }
        let t = Settings {
            seed: 1,
            ..Settings::default()
        };
        assert_ne!(plan(&s, 6000, 5).views, plan(&t, 6000, 5).views);
        // Steps differ from each other.
        assert_ne!(plan(&s, 6000, 5).views, plan(&s, 6000, 6).views);
        // A step's plan does not depend on the total step count except through lr.
        let short = Settings {
            steps: 50,
            ..Settings::default()
        };
        let (a, b) = (plan(&s, 6000, 7), plan(&short, 6000, 7));
        assert_eq!((a.views, a.negatives), (b.views, b.negatives));
    }

    #[test]
    fn ranges_and_phases_follow_the_paper() {
        let s = Settings::default();
        let mut kinds = HashSet::new();
        for step in 0..s.steps {
            let p = plan(&s, 6000, step);
            assert_eq!(p.views.len(), 3);
            assert_eq!(p.negatives.len(), 128);
            assert_eq!(p.negatives.iter().collect::<HashSet<_>>().len(), 128);
            assert_eq!(p.prior, step >= 100);
            assert!((p.lr - 10.0 * (1.0 - step as f64 / 300.0)).abs() < 1e-12);
            for v in &p.views {
                assert!((0.0..std::f64::consts::TAU).contains(&v.yaw));
                assert!(v.pitch.abs() <= std::f64::consts::PI / 14.0);
                assert!((2.0..=4.0).contains(&v.distance));
                let gray = matches!(v.background, Background::Gray { .. });
                assert_eq!(gray, step < 25, "step {step}: {:?}", v.background);
                if let Background::Gray { level } = v.background {
                    assert!((0.0..=1.0).contains(&level));
                }
                kinds.insert(v.background.name());
            }
        }
        assert_eq!(kinds.len(), 4, "{kinds:?}");
    }

    #[test]
    fn augmented_backgrounds_are_roughly_uniform() {
        let s = Settings::default();
        let mut counts = [0usize; 3];
        for step in 25..2025 {
            for v in plan(&s, 10, step).views {
                counts[match v.background {
                    Background::Checkerboard { .. } => 0,
                    Background::Noise { .. } => 1,
                    Background::Fourier { .. } => 2,
                    Background::Gray { .. } => unreachable!(),
                }] += 1;
            }
        }
        // 6000 draws, p = 1/3: sd = sqrt(6000 · 2/9) ≈ 36.5; ±200 is > 5 sd.
        for c in counts {
            assert!((1800..=2200).contains(&c), "{counts:?}");
        }
    }

    #[test]
    fn small_pools_and_fixed_views() {
        let s = Settings::default();
        assert_eq!(plan(&s, 5, 0).negatives.len(), 5);
        assert!(plan(&s, 0, 0).negatives.is_empty());
        let v0 = View::initial(&s);
        assert_eq!((v0.yaw, v0.pitch, v0.distance), (0.0, 0.0, 3.0));
        let o = View::orbit(&s, 4);
        assert!((o[1].yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
    }

    #[test]
    fn time_steps_are_stratified_and_shared_between_steps() {
        let s = Settings::default();
        let n = 7;
        // Over each round every time step appears once.
        for round in 0..3 {
            let mut seen: Vec<usize> = (0..n).map(|k| time_order(round * n + k, n, 5)).collect();
            seen.sort();
            assert_eq!(seen, (0..n).collect::<Vec<_>>());
        }
        let mut a = plan(&s, 10, 4);
        let mut b = plan(&s, 10, 5);
        assign_times(&mut a, n, 5);
        assign_times(&mut b, n, 5);
        assert_eq!(a.views[1].time, b.views[0].time);
        assert_eq!(a.views[2].time, b.views[1].time);
        // One volume: nothing changes.
        let mut c = plan(&s, 10, 4);
        assign_times(&mut c, 1, 5);
        assert_eq!(c, plan(&s, 10, 4));
        assert_eq!(preview_times(1), [0]);
        assert_eq!(preview_times(9), [0, 4, 8]);
    }
}
