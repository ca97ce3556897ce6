//! An offline demonstration that needs no model download: the optimizer recovers a known
//! transfer function of a real volume from reference pictures alone.
//!
//! A TF that shows the aneurism's vessels in two colours renders 8 reference views. The
//! optimizer starts from the paper's initialization (densities from the histogram, grey-ish
//! colours) and descends on the pixel difference to those pictures — the same renderer
//! backward, TF backward and SGD that `t2tf optimize` drives with CLIP — then renders 4 views
//! it never saw. The sheet it writes has three rows: the reference TF, the initialization, and
//! the recovered TF, on those unseen views.
//!
//! ```sh
//! cargo run --release --example demo_recover -- [--out docs/demo_recover.png] [--steps 200]
//! ```
//!
//! What CLIP adds in `t2tf optimize`: the target is a sentence instead of pictures, so nobody
//! has to know the TF in advance; with the tiny random test CLIP that signal is meaningless,
//! which is why this demonstration uses pictures.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use t2tf::camera::UpAxis;
use t2tf::image::Image;
use t2tf::optimize::adapters::{PaperTf, VolumeRenderer};
use t2tf::optimize::recover::{descend, pixel_loss, psnr};
use t2tf::optimize::{initialize, Background, Parameterization, Renderer, Settings, View};
use t2tf::render::RenderOptions;
use t2tf::tf::ControlPoints;
use t2tf::volume::{load, ReadOptions};

const VOLUME: &str = "../shared/data/volumes/aneurism_256x256x256_uint8.raw";
/// Control points of both TFs (the reference is representable).
const K: usize = 8;
const SIZE: usize = 160;
const LUT: usize = 256;

/// Vessels: the low values (air/tissue) clear, the contrast-filled vessels red to yellow, the
/// brightest (the aneurism's dense rim) white.
fn reference_tf() -> ControlPoints {
    ControlPoints {
        x: (0..K).map(|i| i as f64 / (K - 1) as f64).collect(),
        sigma: vec![0.0, 0.0, 8.0, 40.0, 90.0, 140.0, 200.0, 255.0],
        rgb: vec![
            [0.0, 0.0, 0.0],
            [0.6, 0.1, 0.1],
            [0.8, 0.15, 0.1],
            [0.9, 0.3, 0.1],
            [0.95, 0.6, 0.2],
            [1.0, 0.85, 0.4],
            [1.0, 0.95, 0.8],
            [1.0, 1.0, 1.0],
        ],
    }
}

fn views(n: usize, offset: f64, pitch: f64, textured: bool) -> Vec<View> {
    (0..n)
        .map(|i| View {
            yaw: std::f64::consts::TAU * (i as f64 + offset) / n as f64,
            pitch: if i % 2 == 0 { pitch } else { -pitch },
            distance: 2.6,
            background: if textured {
                Background::Checkerboard { seed: i as u64 }
            } else {
                Background::Gray { level: 0.15 }
            },
            seed: 0,
            time: 0,
        })
        .collect()
}

fn render_all(r: &VolumeRenderer, cp: &ControlPoints, views: &[View]) -> Result<Vec<Image>> {
    let lut = cp.to_lut(LUT);
    views
        .iter()
        .map(|v| {
            r.render(&lut, v)
                .map(|x| x.0)
                .map_err(|e| anyhow::anyhow!("{e}"))
        })
        .collect()
}

/// Seconds between progress lines: the descent takes about 100 s at the default steps.
const LINE_EVERY: Duration = Duration::from_secs(5);

/// When to say how far the descent is: at the first step (so a reader sees it started), then
/// every `LINE_EVERY`, and at the last.
struct Pacer {
    last: Option<Instant>,
}

impl Pacer {
    fn due(&mut self, now: Instant, step: usize, steps: usize) -> bool {
        let due = step == steps || self.last.is_none_or(|t| now - t >= LINE_EVERY);
        if due {
            self.last = Some(now);
        }
        due
    }
}

fn main() -> Result<()> {
    let mut out = PathBuf::from("demo_recover.png");
    let mut steps = 200usize;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--out" => out = args.next().context("--out needs a path")?.into(),
            "--steps" => steps = args.next().context("--steps needs a number")?.parse()?,
            other => anyhow::bail!("unknown argument {other} (use --out PNG, --steps N)"),
        }
    }
    let volume = load(Path::new(VOLUME), &ReadOptions::default())
        .with_context(|| format!("{VOLUME} (the shared volumes beside the repository)"))?;
    let r = VolumeRenderer {
        backend: t2tf::render::shared_backend(),
        volume: &volume,
        series: None,
        options: RenderOptions::default(),
        up: UpAxis::Z,
        size: SIZE,
        render_size: SIZE,
        jitter: false,
    };
    let tf = PaperTf {
        k: K,
        lut_size: LUT,
    };
    // Training views on checkerboards (a colour equal to a flat background would look
    // transparent); held-out views at other angles on a dark background never trained on.
    let train = views(8, 0.0, 0.2, true);
    let held = views(4, 0.37, 0.35, false);
    let targets = render_all(&r, &reference_tf(), &train)?;
    let settings = Settings {
        control_points: K,
        seed: 3,
        ..Settings::default()
    };
    let (p0, _) = initialize(&r, &tf, &volume.histogram, &settings.validate()?)?;
    let t0 = Instant::now();
    println!("descending {steps} steps × 8 views at {SIZE}²");
    // The loss is evaluated once per step: wrapped, it says how far the descent is.
    let mut loss = pixel_loss(&targets);
    let mut pacer = Pacer { last: None };
    let mut step = 0;
    let mut paced = |images: &[Image]| {
        let r = loss(images);
        step += 1;
        if let Ok((l, _)) = &r {
            if pacer.due(Instant::now(), step, steps) {
                println!(
                    "step {step}/{steps}  pixel loss {l:.5}  {:.0} s",
                    t0.elapsed().as_secs_f64()
                );
            }
        }
        r
    };
    // lr 30, the recovery test's measured best on the nucleon.
    let (p, losses) = descend(&r, &tf, &train, p0.clone(), steps, 30.0, &mut paced)?;
    let secs = t0.elapsed().as_secs_f64();
    let cp0 = tf.control_points(&p0).map_err(|e| anyhow::anyhow!("{e}"))?;
    let cp = tf.control_points(&p).map_err(|e| anyhow::anyhow!("{e}"))?;
    let want = render_all(&r, &reference_tf(), &held)?;
    let before = render_all(&r, &cp0, &held)?;
    let after = render_all(&r, &cp, &held)?;
    println!(
        "{steps} steps × 8 views at {SIZE}² in {secs:.1} s; pixel loss {:.5} → {:.5}",
        losses[0],
        losses.last().copied().unwrap_or(f64::NAN)
    );
    println!(
        "held-out views: initialization {:.1} dB, recovered {:.1} dB PSNR against the reference",
        psnr(&before, &want),
        psnr(&after, &want)
    );
    let rows: Vec<Image> = want.into_iter().chain(before).chain(after).collect();
    Image::grid(&rows, 4).save_png(&out)?;
    println!(
        "wrote {} (rows: reference, initialization, recovered)",
        out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_lines_come_first_every_few_seconds_and_last() {
        let t = Instant::now();
        let mut p = Pacer { last: None };
        assert!(p.due(t, 1, 200), "the first step is said");
        assert!(!p.due(t + Duration::from_secs(1), 2, 200));
        assert!(!p.due(t + Duration::from_millis(4900), 40, 200));
        assert!(p.due(t + LINE_EVERY, 41, 200));
        assert!(!p.due(t + LINE_EVERY + Duration::from_secs(1), 42, 200));
        assert!(
            p.due(t + LINE_EVERY + Duration::from_secs(1), 200, 200),
            "the last step is said"
        );
    }
}
