//! VTK's "Lab/CIEDE2000" interpolation: the shortest path between two colours through a
//! 17³ grid of RGB colours (26-neighbourhood, edge cost ΔE2000), found by Dijkstra from the
//! second colour, then followed in Lab at positions proportional to the path length and
//! rounded to 8 bits (VTK evaluates the path with `MapValue`). Same grid, same visiting order
//! and tie-breaking as VTK, so the same path.

use std::collections::BTreeSet;
use std::f64::consts::PI;

use super::color_convert::rgb_to_lab;

const GRID: i32 = 17;
type Pos = [i32; 3];

fn position(c: [f64; 3]) -> Pos {
    c.map(|v| (v * (GRID - 1) as f64 + 0.5) as i32)
}

fn grid_rgb(p: Pos) -> [f64; 3] {
    p.map(|v| v as f64 / (GRID - 1) as f64)
}

/// The grid colour VTK snaps an end colour to before searching.
pub(crate) fn snap(c: [f64; 3]) -> [f64; 3] {
    grid_rgb(position(c))
}

fn index(p: Pos) -> usize {
    (p[0] + GRID * (p[1] + GRID * p[2])) as usize
}

fn hue(b: f64, a: f64) -> f64 {
    if b == 0.0 && a == 0.0 {
        return 0.0;
    }
    let h = b.atan2(a);
    if h < 0.0 {
        h + 2.0 * PI
    } else {
        h
    }
}

/// CIEDE2000 colour difference (k_L = k_C = k_H = 1).
pub(crate) fn delta_e(l1: [f64; 3], l2: [f64; 3]) -> f64 {
    let norm = |a: f64, b: f64| (a * a + b * b).sqrt();
    let c1 = norm(l1[1], l1[2]);
    let c2 = norm(l2[1], l2[2]);
    let bar_c7 = (0.5 * (c1 + c2)).powf(7.0);
    let g = 0.5 * (1.0 - (bar_c7 / (bar_c7 + 25f64.powf(7.0))).sqrt());
    let (a1, a2) = ((1.0 + g) * l1[1], (1.0 + g) * l2[1]);
    let (cp1, cp2) = (norm(a1, l1[2]), norm(a2, l2[2]));
    let (h1, h2) = (hue(l1[2], a1), hue(l2[2], a2));
    let product = cp1 * cp2;
    let mut dh = 0.0;
    if product != 0.0 {
        dh = h2 - h1;
        if dh < -PI {
            dh += 2.0 * PI;
        } else if dh > PI {
            dh -= 2.0 * PI;
        }
    }
    let d_l = l2[0] - l1[0];
    let d_c = cp2 - cp1;
    let d_h = 2.0 * product.sqrt() * (0.5 * dh).sin();
    let bar_l = 0.5 * (l1[0] + l2[0]);
    let bar_cp = 0.5 * (cp1 + cp2);
    let sum = h1 + h2;
    let bar_h = if product == 0.0 {
        sum
    } else if (h1 - h2).abs() <= PI {
        0.5 * sum
    } else if sum < 2.0 * PI {
        0.5 * (sum + 2.0 * PI)
    } else {
        0.5 * (sum - 2.0 * PI)
    };
    let deg = PI / 180.0;
    let t = 1.0 - 0.17 * (bar_h - 30.0 * deg).cos()
        + 0.24 * (2.0 * bar_h).cos()
        + 0.32 * (3.0 * bar_h + 6.0 * deg).cos()
        - 0.20 * (4.0 * bar_h - 63.0 * deg).cos();
    let d_theta = 30.0 * deg * (-((bar_h - 275.0 * deg) / (25.0 * deg)).powf(2.0)).exp();
    let cp7 = bar_cp.powf(7.0);
    let r_c = 2.0 * (cp7 / (cp7 + 25f64.powf(7.0))).sqrt();
    let dl50 = (bar_l - 50.0).powf(2.0);
    let s_l = 1.0 + 0.015 * dl50 / (20.0 + dl50).sqrt();
    let s_c = 1.0 + 0.045 * bar_cp;
    let s_h = 1.0 + 0.015 * bar_cp * t;
    let r_t = -(2.0 * d_theta).sin() * r_c;
    let (ql, qc, qh) = (d_l / s_l, d_c / s_c, d_h / s_h);
    (ql.powf(2.0) + qc.powf(2.0) + qh.powf(2.0) + r_t * qc * qh).sqrt()
}

/// Non-negative finite distances ordered as f64 (what VTK's std::set of pairs does).
#[derive(Clone, Copy, PartialEq)]
struct Dist(f64);
impl PartialOrd for Dist {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Eq for Dist {}
impl Ord for Dist {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0)
    }
}

/// Dijkstra from `to` over the grid: distances and predecessors of every grid point.
fn search(to: Pos) -> (Vec<f64>, Vec<Pos>) {
    let n = (GRID * GRID * GRID) as usize;
    let mut dist = vec![f64::INFINITY; n];
    let mut pred = vec![[0; 3]; n];
    let mut front = BTreeSet::new();
    dist[index(to)] = 0.0;
    front.insert((Dist(0.0), to));
    while let Some((Dist(d), p)) = front.pop_first() {
        let lab = rgb_to_lab(grid_rgb(p));
        let range = |i: usize| (p[i] - 1).max(0)..=(p[i] + 1).min(GRID - 1);
        for z in range(2) {
            for y in range(1) {
                for x in range(0) {
                    let q = [x, y, z];
                    if q == p {
                        continue;
                    }
                    let nd = d + delta_e(lab, rgb_to_lab(grid_rgb(q)));
                    let old = dist[index(q)];
                    if nd < old {
                        front.remove(&(Dist(old), q));
                        dist[index(q)] = nd;
                        pred[index(q)] = p;
                        front.insert((Dist(nd), q));
                    }
                }
            }
        }
    }
    (dist, pred)
}

/// The path from `c1` to `c2` as (fraction of the path length, grid colour), as VTK adds
/// it to its helper Lab map. One point when both snap to the same grid colour.
pub(crate) fn color_path(c1: [f64; 3], c2: [f64; 3]) -> Vec<(f64, [f64; 3])> {
    let (p1, p2) = (position(c1), position(c2));
    let (dist, pred) = search(p2);
    let total = dist[index(p1)];
    let mut path = Vec::new();
    let mut p = p1;
    loop {
        path.push((total - dist[index(p)], grid_rgb(p)));
        if p == p2 {
            break;
        }
        p = pred[index(p)];
    }
    if path.len() > 1 {
        path.iter_mut().for_each(|n| n.0 /= total);
    }
    path
}
