//! Every setting of the optimization, with the paper's defaults (Appendix A; docs/DESIGN.md).
//!
//! The constants in [`defaults`] are the single source: `Settings::default()` and the clap
//! flags of `t2tf optimize` both read them, so `--help` prints what the code uses.
//!
//! [`Settings`] is what a caller fills in; [`ValidSettings`] is what the driver and the loop
//! take. Only [`Settings::validate`] builds the latter, so the checks run once, where the
//! settings are made, and nothing downstream repeats them.

use serde::{Deserialize, Serialize};

use super::OptimizeError;

/// The paper's settings.
pub mod defaults {
    /// SGD steps (paper: 300).
    pub const STEPS: usize = 300;
    /// Random views rendered per step, gradients averaged (paper: 3).
    pub const VIEWS: usize = 3;
    /// Initial learning rate, annealed linearly to 0 (paper: 10).
    pub const LR: f64 = 10.0;
    /// SGD momentum (paper: 0.75).
    pub const MOMENTUM: f64 = 0.75;
    /// Weight of the Beta prior on T_N (paper: data dependent; 0.02 in docs/DESIGN.md).
    pub const PRIOR_WEIGHT: f64 = 0.02;
    /// a = b of the Beta prior; < 1 biases rays towards fully opaque or fully clear.
    pub const PRIOR_AB: f64 = 0.5;
    /// First step (0-based) with the prior switched on (paper: 100).
    pub const PRIOR_START: usize = 100;
    /// λ1, L1 on control-point densities (paper: 2e-5).
    pub const L1: f64 = 2e-5;
    /// λ2, L2 of colours towards 0.5 (paper: 8e-4).
    pub const L2: f64 = 8e-4;
    /// Control points of the TF. The paper does not state its count; 32 points resolve
    /// features 1/31 of the value range wide (8 histogram bins), and the L1 term keeps
    /// unused points at zero density, so the exported TF stays small enough to edit by hand.
    pub const CONTROL_POINTS: usize = 32;
    /// Negatives drawn from the caption pool per step (paper: 128).
    pub const NEGATIVES_PER_STEP: usize = 128;
    /// Steps with a constant gray background before background augmentation (paper: 25).
    pub(crate) const GRAY_STEPS: usize = 25;
    /// Target mean transmittance of view V0 after initialization (paper: ρ = 0.05).
    pub(crate) const RHO: f64 = 0.05;
    /// Seed of every random choice (views, backgrounds, negatives, initial colours).
    pub const SEED: u64 = 0;
    /// Pitch limit of random views, ±π/14 (paper; defined with the camera).
    pub(crate) const PITCH_LIMIT: f64 = crate::camera::PITCH_RANGE;
    /// Camera distance range in bounding radii (paper: 2 to 4; defined with the camera).
    pub(crate) const DISTANCE: [f64; 2] = crate::camera::DISTANCE_RANGE;
}

/// All numeric settings of one optimization run (what `report.json` records), unchecked;
/// [`Settings::validate`] turns them into the [`ValidSettings`] a run takes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    /// SGD steps (`--steps`; 0: the result is the initialization).
    pub steps: usize,
    /// Random views per step, gradients averaged (`--views`).
    pub views: usize,
    /// Initial learning rate, annealed linearly to 0 (`--lr`).
    pub lr: f64,
    /// SGD momentum in [0, 1) (`--momentum`).
    pub momentum: f64,
    /// Weight of the Beta prior on T_N (`--prior-weight`).
    pub prior_weight: f64,
    /// Beta(a, b) parameter a (`--prior-ab`).
    pub prior_a: f64,
    /// Beta(a, b) parameter b (`--prior-ab`).
    pub prior_b: f64,
    /// First step (0-based) with the prior on (`--prior-start`).
    pub prior_start: usize,
    /// λ1: L1 weight on control-point densities (`--l1`).
    pub l1: f64,
    /// λ2: L2 weight of colours towards 0.5 (`--l2`).
    pub l2: f64,
    /// Control points of the TF (`--control-points`, at least 2).
    pub control_points: usize,
    /// Negatives drawn from the caption pool per step (`--negatives-per-step`).
    pub negatives_per_step: usize,
    /// Steps with a constant gray background before background augmentation.
    pub gray_steps: usize,
    /// Target mean transmittance of view V0 after initialization, in (0, 1).
    pub rho: f64,
    /// Seed of every random choice (`--seed`).
    pub seed: u64,
    /// Pitch limit of random views in radians, in [0, π/2).
    pub pitch_limit: f64,
    /// [min, max] camera distance in bounding radii.
    pub distance: [f64; 2],
}

/// [`Settings`] that passed [`Settings::validate`], the only way to build one: the driver
/// and the loop take them as given. Reads as `Settings` through `Deref`.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(transparent)]
pub struct ValidSettings(Settings);

impl std::ops::Deref for ValidSettings {
    type Target = Settings;

    fn deref(&self) -> &Settings {
        &self.0
    }
}

impl ValidSettings {
    /// The settings themselves (for `report.json`, or to change one and validate again).
    pub fn into_inner(self) -> Settings {
        self.0
    }
}

impl Default for Settings {
    fn default() -> Settings {
        use defaults::*;
        Settings {
            steps: STEPS,
            views: VIEWS,
            lr: LR,
            momentum: MOMENTUM,
            prior_weight: PRIOR_WEIGHT,
            prior_a: PRIOR_AB,
            prior_b: PRIOR_AB,
            prior_start: PRIOR_START,
            l1: L1,
            l2: L2,
            control_points: CONTROL_POINTS,
            negatives_per_step: NEGATIVES_PER_STEP,
            gray_steps: GRAY_STEPS,
            rho: RHO,
            seed: SEED,
            pitch_limit: PITCH_LIMIT,
            distance: DISTANCE,
        }
    }
}

/// The largest sizes a run accepts, so that a size from a flag or a caller is refused at once
/// instead of being allocated: each is far above what a run needs (the paper: 300 steps, 3
/// views, 32 control points) and small enough that what it sizes fits any machine.
pub mod limits {
    /// Steps of one run (a million default steps take days).
    pub const STEPS: usize = 1_000_000;
    /// Views per step: each is a render and a CLIP pass held until the step's backward.
    pub const VIEWS: usize = 64;
    /// Control points of the TF: ParaView's tables resolve about 16,000 entries over the data
    /// range (README, "Output folder"), and the exported points keep 1/16000 apart.
    pub const CONTROL_POINTS: usize = 4096;
}

impl Settings {
    /// Check every setting; the error names the setting. `steps = 0` is valid (the result is
    /// the initialization).
    pub fn validate(&self) -> Result<ValidSettings, OptimizeError> {
        let bad =
            |name: &'static str, message: String| Err(OptimizeError::Setting { name, message });
        let finite_nonneg = |v: f64| v.is_finite() && v >= 0.0;
        if self.steps > limits::STEPS {
            return bad(
                "steps",
                format!("must be at most {}, got {}", limits::STEPS, self.steps),
            );
        }
        if self.views == 0 {
            return bad("views", "must be at least 1".into());
        }
        if self.views > limits::VIEWS {
            return bad(
                "views",
                format!("must be at most {}, got {}", limits::VIEWS, self.views),
            );
        }
        if !finite_nonneg(self.lr) {
            return bad("lr", format!("must be finite and ≥ 0, got {}", self.lr));
        }
        if !(0.0..1.0).contains(&self.momentum) {
            return bad(
                "momentum",
                format!("must be in [0, 1), got {}", self.momentum),
            );
        }
        if !finite_nonneg(self.prior_weight) {
            return bad(
                "prior_weight",
                format!("must be finite and ≥ 0, got {}", self.prior_weight),
            );
        }
        for v in [self.prior_a, self.prior_b] {
            if !(v.is_finite() && v > 0.0) {
                return bad("prior_ab", format!("must be finite and > 0, got {v}"));
            }
        }
        if !finite_nonneg(self.l1) {
            return bad("l1", format!("must be finite and ≥ 0, got {}", self.l1));
        }
        if !finite_nonneg(self.l2) {
            return bad("l2", format!("must be finite and ≥ 0, got {}", self.l2));
        }
        if !(2..=limits::CONTROL_POINTS).contains(&self.control_points) {
            return bad(
                "control_points",
                format!(
                    "must be between 2 and {}, got {}",
                    limits::CONTROL_POINTS,
                    self.control_points
                ),
            );
        }
        if !(self.rho > 0.0 && self.rho < 1.0) {
            return bad("rho", format!("must be in (0, 1), got {}", self.rho));
        }
        if !(self.pitch_limit.is_finite()
            && (0.0..std::f64::consts::FRAC_PI_2).contains(&self.pitch_limit))
        {
            return bad(
                "pitch_limit",
                format!("must be in [0, π/2), got {}", self.pitch_limit),
            );
        }
        let [d0, d1] = self.distance;
        if !(d0.is_finite() && d1.is_finite() && d0 > 0.0 && d1 >= d0) {
            return bad(
                "distance",
                format!("range must be 0 < min ≤ max, got [{d0}, {d1}]"),
            );
        }
        Ok(ValidSettings(self.clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_beyond_the_limits_are_refused_naming_the_setting() {
        for (name, change) in [
            (
                "steps",
                (|s: &mut Settings| s.steps = 1_000_000_000_000) as fn(&mut Settings),
            ),
            ("steps", |s| s.steps = usize::MAX),
            ("views", |s| s.views = 100_000),
            ("control_points", |s| s.control_points = 10_000_000),
        ] {
            let mut s = Settings::default();
            change(&mut s);
            match s.validate() {
                Err(OptimizeError::Setting { name: n, message }) => {
                    assert_eq!(n, name, "{message}");
                    assert!(message.contains("at most") || message.contains("between"));
                }
                other => panic!("{name}: {other:?}"),
            }
        }
        let mut s = Settings::default();
        (s.steps, s.views, s.control_points) =
            (limits::STEPS, limits::VIEWS, limits::CONTROL_POINTS);
        assert!(s.validate().is_ok());
    }

    #[test]
    fn defaults_are_the_papers_and_valid() {
        let s = Settings::default();
        assert_eq!((s.steps, s.views, s.lr, s.momentum), (300, 3, 10.0, 0.75));
        assert_eq!(
            (s.prior_start, s.prior_weight, s.prior_a, s.prior_b),
            (100, 0.02, 0.5, 0.5)
        );
        assert_eq!(
            (s.l1, s.l2, s.negatives_per_step, s.gray_steps),
            (2e-5, 8e-4, 128, 25)
        );
        assert_eq!(s.rho, 0.05);
        s.validate().unwrap();
    }

    #[test]
    fn invalid_settings_name_the_setting() {
        // By the field's name, in backticks, and in the hint a front end words from.
        let check = |f: fn(&mut Settings), name: &'static str| {
            let mut s = Settings::default();
            f(&mut s);
            let e = s.validate().unwrap_err();
            let m = e.to_string();
            assert!(m.contains(&format!("`{name}`")), "{m} should name {name}");
            assert_eq!(e.hint(), crate::error::Hint::invalid(name), "{m}");
        };
        check(|s| s.views = 0, "views");
        check(|s| s.lr = f64::NAN, "lr");
        check(|s| s.momentum = 1.0, "momentum");
        check(|s| s.prior_a = 0.0, "prior_ab");
        check(|s| s.l1 = -1.0, "l1");
        check(|s| s.control_points = 1, "control_points");
        check(|s| s.rho = 1.0, "rho");
        check(|s| s.pitch_limit = 2.0, "pitch_limit");
        check(|s| s.distance = [2.0, 1.0], "distance");
        let s = Settings {
            steps: 0,
            ..Settings::default()
        };
        s.validate().unwrap();
    }
}
