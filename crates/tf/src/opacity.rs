//! σ ↔ ParaView/VTK opacity with a unit distance (docs/DESIGN.md "Conventions"):
//! o = 1 − exp(−σ u / L), u = ScalarOpacityUnitDistance (world units), L = longest box side.
//! VTK corrects o for its sample distance Δ as 1 − (1 − o)^(Δ/u) = 1 − exp(−σ Δ / L): exactly
//! our renderer's α for a step Δ, whatever u is. u only decides how well o resolves σ.

use super::SIGMA_MAX;
use t2tf_volume::Geometry;

/// Per-point opacity for density `sigma` at unit distance `u` in a box of longest side `l`.
pub fn sigma_to_opacity(sigma: f64, u: f64, l: f64) -> f64 {
    -(-sigma * u / l).exp_m1()
}

/// Inverse of [`sigma_to_opacity`], clamped to the paper's density range [0, 255]: o = 1 (or
/// a σ beyond 255, possible in a foreign preset) reads as 255; o ≤ 0 or NaN as 0.
pub fn opacity_to_sigma(o: f64, u: f64, l: f64) -> f64 {
    opacity_to_sigma_within(o, u, l, SIGMA_MAX)
}

/// [`opacity_to_sigma`] clamped to [0, `sigma_max`] instead.
pub fn opacity_to_sigma_within(o: f64, u: f64, l: f64, sigma_max: f64) -> f64 {
    if o.is_nan() || o <= 0.0 {
        return 0.0;
    }
    if o >= 1.0 {
        return sigma_max;
    }
    (-(-o).ln_1p() * l / u).clamp(0.0, sigma_max)
}

/// The unit distance written into every export unless the user picks one: the mean voxel
/// spacing. Why: VTK samples about once per voxel, so o is then the opacity of one voxel
/// step; per-point opacities stay well inside (0, 1) (σ = 255 on a 64-voxel-wide box gives
/// o ≈ 0.98, not 1 − 1e-111), so printed values keep σ's resolution and a user editing
/// the curve in ParaView sees familiar per-voxel opacities.
pub fn default_unit_distance(g: &Geometry) -> f64 {
    let u = g.spacing.iter().sum::<f64>() / 3.0;
    if u.is_finite() && u > 0.0 {
        u
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opacity_round_trips_and_matches_vtk_correction() {
        let (u, l) = (1.0, 63.0);
        for sigma in [0.0, 1e-9, 0.5, 12.0, 100.0, 255.0] {
            let o = sigma_to_opacity(sigma, u, l);
            assert!((0.0..1.0).contains(&o));
            let back = opacity_to_sigma(o, u, l);
            assert!(
                (back - sigma).abs() <= 1e-12 * (1.0 + sigma),
                "{sigma} -> {back}"
            );
            // VTK's correction for a sample distance Δ gives our α for a step Δ.
            let delta = 0.37;
            let vtk = 1.0 - (1.0 - o).powf(delta / u);
            let ours = 1.0 - (-sigma * delta / l).exp();
            assert!((vtk - ours).abs() < 1e-12);
        }
        assert_eq!(opacity_to_sigma(1.0, u, l), 255.0);
        assert_eq!(opacity_to_sigma(f64::NAN, u, l), 0.0);
        assert_eq!(opacity_to_sigma(-0.5, u, l), 0.0);
        let g = Geometry {
            dims: [4, 4, 4],
            spacing: [1.0, 2.0, 3.0],
            origin: [0.0; 3],
        };
        assert_eq!(default_unit_distance(&g), 2.0);
    }
}
