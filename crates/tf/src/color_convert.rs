//! Colour conversions as VTK's `vtkMath` does them (sRGB with its gamma, D65 white with
//! VTK's rounded constants, Lab with the 0.008856 / 7.787 linear toe, out-of-gamut RGB scaled
//! down by its largest channel and floored at 0). ParaView interpolates in these spaces, so
//! matching its colours needs these exact formulas, not textbook ones.

const SIXTH: f64 = 1.0 / 6.0;

/// VTK's D65 reference white (X, Y, Z).
const WHITE: [f64; 3] = [0.9505, 1.0, 1.089];

pub(crate) fn rgb_to_hsv(c: [f64; 3]) -> [f64; 3] {
    let [r, g, b] = c;
    // VTK finds min and max with an `else if`, so a green above r never lowers the min:
    // kept because it decides the hue of some ties.
    let (mut max, mut min) = (r, r);
    if g > max {
        max = g;
    } else if g < min {
        min = g;
    }
    if b > max {
        max = b;
    } else if b < min {
        min = b;
    }
    let s = if max > 0.0 { (max - min) / max } else { 0.0 };
    if s <= 0.0 {
        return [0.0, s, max];
    }
    let d = max - min;
    let mut h = if r == max {
        SIXTH * (g - b) / d
    } else if g == max {
        1.0 / 3.0 + SIXTH * (b - r) / d
    } else {
        2.0 / 3.0 + SIXTH * (r - g) / d
    };
    if h < 0.0 {
        h += 1.0;
    }
    [h, s, max]
}

pub(crate) fn hsv_to_rgb(hsv: [f64; 3]) -> [f64; 3] {
    let [h, s, v] = hsv;
    let sixth = 1.0 / 6.0;
    let (third, two_thirds, five_sixths) = (1.0 / 3.0, 2.0 / 3.0, 5.0 / 6.0);
    let pure = if h > sixth && h <= third {
        [(third - h) / sixth, 1.0, 0.0]
    } else if h > third && h <= 0.5 {
        [0.0, 1.0, (h - third) / sixth]
    } else if h > 0.5 && h <= two_thirds {
        [0.0, (two_thirds - h) / sixth, 1.0]
    } else if h > two_thirds && h <= five_sixths {
        [(h - two_thirds) / sixth, 0.0, 1.0]
    } else if h > five_sixths && h <= 1.0 {
        [1.0, 0.0, (1.0 - h) / sixth]
    } else {
        [1.0, h / sixth, 0.0]
    };
    // VTK's formula can round past 1 at a sector edge (h = 1/2: (1/2 − 1/3)/(1/6) = 1 + 2⁻⁵²);
    // the GPU clamps what it uploads, and the exporter's [0, 1] check would refuse the colour
    // (ParaView's own "Blue to Red Rainbow" preset hit this).
    pure.map(|p| ((s * p + (1.0 - s)) * v).clamp(0.0, 1.0))
}

fn rgb_to_xyz(c: [f64; 3]) -> [f64; 3] {
    let [r, g, b] = c.map(|v| {
        if v > 0.04045 {
            ((v + 0.055) / 1.055).powf(2.4)
        } else {
            v / 12.92
        }
    });
    [
        r * 0.4124 + g * 0.3576 + b * 0.1805,
        r * 0.2126 + g * 0.7152 + b * 0.0722,
        r * 0.0193 + g * 0.1192 + b * 0.9505,
    ]
}

fn xyz_to_rgb(xyz: [f64; 3]) -> [f64; 3] {
    let [x, y, z] = xyz;
    let lin = [
        x * 3.2406 + y * -1.5372 + z * -0.4986,
        x * -0.9689 + y * 1.8758 + z * 0.0415,
        x * 0.0557 + y * -0.2040 + z * 1.0570,
    ];
    let mut c = lin.map(|v| {
        if v > 0.0031308 {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        } else {
            12.92 * v
        }
    });
    let max = c[0].max(c[1]).max(c[2]);
    if max > 1.0 {
        c = c.map(|v| v / max);
    }
    c.map(|v| v.max(0.0))
}

fn xyz_to_lab(xyz: [f64; 3]) -> [f64; 3] {
    let f = |v: f64| {
        if v > 0.008856 {
            v.powf(1.0 / 3.0)
        } else {
            7.787 * v + 16.0 / 116.0
        }
    };
    let [x, y, z] = [0, 1, 2].map(|i| f(xyz[i] / WHITE[i]));
    [116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)]
}

fn lab_to_xyz(lab: [f64; 3]) -> [f64; 3] {
    let [l, a, b] = lab;
    let y = (l + 16.0) / 116.0;
    let f = [a / 500.0 + y, y, y - b / 200.0];
    let inv = |v: f64| {
        if v.powi(3) > 0.008856 {
            v.powi(3)
        } else {
            (v - 16.0 / 116.0) / 7.787
        }
    };
    [0, 1, 2].map(|i| WHITE[i] * inv(f[i]))
}

pub(crate) fn rgb_to_lab(c: [f64; 3]) -> [f64; 3] {
    xyz_to_lab(rgb_to_xyz(c))
}

pub(crate) fn lab_to_rgb(lab: [f64; 3]) -> [f64; 3] {
    xyz_to_rgb(lab_to_xyz(lab))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hsv_sector_edges_stay_in_the_unit_cube() {
        // h = 1/2 gives (1/2 − 1/3)/(1/6) = 1 + 2⁻⁵² in f64 without the clamp.
        for h in [0.0, 1.0 / 6.0, 1.0 / 3.0, 0.5, 2.0 / 3.0, 5.0 / 6.0, 1.0] {
            let c = hsv_to_rgb([h, 1.0, 1.0]);
            assert!(c.iter().all(|v| (0.0..=1.0).contains(v)), "h = {h}: {c:?}");
        }
        assert_eq!(hsv_to_rgb([0.5, 1.0, 1.0]), [0.0, 1.0, 1.0]);
    }

    #[test]
    fn round_trips_stay_close() {
        for c in [
            [0.2, 0.5, 0.9],
            [1.0, 0.0, 0.0],
            [0.05, 0.05, 0.05],
            [0.9, 0.9, 0.2],
        ] {
            let h = hsv_to_rgb(rgb_to_hsv(c));
            let l = lab_to_rgb(rgb_to_lab(c));
            for i in 0..3 {
                assert!((h[i] - c[i]).abs() < 1e-12, "{c:?} {h:?}");
                // VTK's rounded matrices are not exact inverses: 1e-3 is what they allow.
                assert!((l[i] - c[i]).abs() < 1e-3, "{c:?} {l:?}");
            }
        }
    }
}
