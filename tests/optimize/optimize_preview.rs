//! preview.png's level: a picture for people picks its mip level by its pixel footprint as the
//! loop does (`render::choose_level`), so a volume with more voxels than the picture has pixels
//! is not rendered (copied, or paged through the brick cache) at full resolution for it, and
//! the picture stays within 40 dB PSNR of level 0's.
//!
//! The volume is the 256³ aneurism upsampled to 512³: a level 1 as detailed as its source. On
//! the real 256³ aneurism a filtered level differs from level 0 by its averaged values, not by
//! resolution (level 1 at 36–37 dB against level 0 with this TF, whatever the picture's size),
//! so this measures the choice of level, not the filter.

use std::path::Path;

use t2tf::camera::UpAxis;
use t2tf::image::psnr;
use t2tf::optimize::adapters::VolumeRenderer;
use t2tf::optimize::{Settings, View};
use t2tf::render::RenderOptions;
use t2tf::tf::ControlPoints;
use t2tf::volume::{ByteOrder, Geometry, ScalarType, TypedBuffer, Volume};

/// The 256³ aneurism of ../shared upsampled `f`× trilinearly (cell-centred), as uint8.
fn upsampled_aneurism(f: usize) -> Option<Volume> {
    let path = Path::new("../shared/data/volumes/aneurism_256x256x256_uint8.raw");
    let src = std::fs::read(path).ok()?;
    let n = 256;
    let m = n * f;
    let coord = |i: usize| {
        let c = ((i as f32 + 0.5) / f as f32 - 0.5).clamp(0.0, (n - 1) as f32);
        let i0 = (c.floor() as usize).min(n - 2);
        (i0, c - i0 as f32)
    };
    let axis: Vec<(usize, f32)> = (0..m).map(coord).collect();
    let mut out = vec![0u8; m * m * m];
    for (z, slice) in out.chunks_mut(m * m).enumerate() {
        let (z0, wz) = axis[z];
        for (y, row) in slice.chunks_mut(m).enumerate() {
            let (y0, wy) = axis[y];
            for (x, v) in row.iter_mut().enumerate() {
                let (x0, wx) = axis[x];
                let mut s = 0.0;
                for (dz, cz) in [(0, 1.0 - wz), (1, wz)] {
                    for (dy, cy) in [(0, 1.0 - wy), (1, wy)] {
                        for (dx, cx) in [(0, 1.0 - wx), (1, wx)] {
                            let at = ((z0 + dz) * n + y0 + dy) * n + x0 + dx;
                            s += cz * cy * cx * src[at] as f32;
                        }
                    }
                }
                *v = s.round() as u8;
            }
        }
    }
    let geometry = Geometry {
        dims: [m; 3],
        spacing: [1.0; 3],
        origin: [0.0; 3],
    };
    let buffer = TypedBuffer::new(ScalarType::U8, ByteOrder::Little, out);
    Some(Volume::from_buffer(Path::new("aneurism-upsampled"), geometry, &buffer).unwrap())
}

/// Vessels bright and dense, the rest faint: a TF like the ones the optimizer finds for it.
fn tf() -> ControlPoints {
    ControlPoints {
        x: vec![0.0, 0.15, 0.35, 0.6, 1.0],
        sigma: vec![0.0, 0.0, 8.0, 60.0, 120.0],
        rgb: vec![
            [0.2, 0.2, 0.8],
            [0.3, 0.3, 0.8],
            [0.9, 0.4, 0.3],
            [1.0, 0.8, 0.6],
            [1.0, 1.0, 1.0],
        ],
    }
}

#[test]
fn a_large_volumes_preview_is_rendered_on_a_coarser_level_within_40_db_of_level_0() {
    let Some(volume) = upsampled_aneurism(2) else {
        eprintln!("skipped: ../shared/data/volumes/aneurism_256x256x256_uint8.raw is missing");
        return;
    };
    let renderer = VolumeRenderer {
        backend: t2tf::render::shared_backend(),
        volume: &volume,
        series: None,
        options: RenderOptions::default(),
        up: UpAxis::Z,
        size: 224,
        render_size: 224,
        jitter: false,
    };
    let lut = tf().to_lut(1024);
    // The preview's views (driver: `View::orbit` of the settings).
    for view in View::orbit(&Settings::default(), 2) {
        let camera = t2tf::camera::Camera::orbit(
            &volume.geometry,
            t2tf::camera::Orbit {
                yaw: view.yaw,
                pitch: view.pitch,
                distance: view.distance,
                up: UpAxis::Z,
            },
        )
        .unwrap();
        let size = t2tf::optimize::adapters::PREVIEW_SIZE;
        let chosen = t2tf::render::choose_level(&volume, &camera, size);
        let reference = renderer.render_picture(&lut, &view, Some(0)).unwrap();
        let preview = renderer.render_picture(&lut, &view, None).unwrap();
        let db = psnr(&preview, &reference);
        eprintln!(
            "yaw {:.2}: level {chosen}, {db:.1} dB against level 0",
            view.yaw
        );
        assert!(chosen > 0, "a 512³ volume's 256² preview renders level 0");
        // The preview is the chosen level's picture, not level 0's.
        let on_chosen = renderer.render_picture(&lut, &view, Some(chosen)).unwrap();
        assert!(
            preview.data == on_chosen.data,
            "the preview is not level {chosen}'s picture"
        );
        assert!(db.is_finite(), "the preview is level 0's picture");
        assert!(db >= 40.0, "level {chosen}: {db:.1} dB against level 0");
    }
}
