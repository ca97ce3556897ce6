//! The shared volumes (`../shared/data/volumes/`) the render benchmarks measure, as raw files
//! of known dims, spacing and type, and the one way they are read. Each benchmark uses what it
//! needs of it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use t2tf::volume::ScalarType::{self, U16, U8};
use t2tf::volume::{ByteOrder, Geometry, TypedBuffer, Volume};

/// One shared raw volume.
pub struct SharedVolume {
    /// The file in the shared volumes' folder.
    pub file: &'static str,
    /// Points per axis.
    pub dims: [usize; 3],
    /// Spacing per axis.
    pub spacing: [f64; 3],
    /// Its values' type (little-endian).
    pub scalar: ScalarType,
}

/// Every shared volume, in the benchmarks' table order.
pub const SHARED_VOLUMES: [SharedVolume; 7] = [
    shared("aneurism_256x256x256_uint8.raw", [256; 3], [1.0; 3], U8),
    shared(
        "cthead_256x256x99_uint8.raw",
        [256, 256, 99],
        [1.0, 1.0, 2.0],
        U8,
    ),
    shared(
        "headsq_64x64x93_uint16.raw",
        [64, 64, 93],
        [3.2, 3.2, 1.5],
        U16,
    ),
    shared(
        "walnut_128x96x114_uint16.raw",
        [128, 96, 114],
        [1.0; 3],
        U16,
    ),
    shared(
        "hydrogen_atom_128x128x128_uint8.raw",
        [128; 3],
        [1.0; 3],
        U8,
    ),
    shared("neghip_64x64x64_uint8.raw", [64; 3], [1.0; 3], U8),
    shared("nucleon_41x41x41_uint8.raw", [41; 3], [1.0; 3], U8),
];

const fn shared(
    file: &'static str,
    dims: [usize; 3],
    spacing: [f64; 3],
    scalar: ScalarType,
) -> SharedVolume {
    SharedVolume {
        file,
        dims,
        spacing,
        scalar,
    }
}

/// The shared volumes' folder.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/volumes")
}

impl SharedVolume {
    /// Its name: the file's before the dims (`hydrogen_atom`).
    pub fn name(&self) -> &'static str {
        self.file.rsplitn(3, '_').nth(2).unwrap_or(self.file)
    }

    /// Its path.
    pub fn path(&self) -> PathBuf {
        root().join(self.file)
    }

    /// The volume made of the file's `bytes` (as `std::fs::read(self.path())` gives them).
    pub fn volume(&self, bytes: Vec<u8>) -> anyhow::Result<Volume> {
        let geometry = Geometry {
            dims: self.dims,
            spacing: self.spacing,
            origin: [0.0; 3],
        };
        let buffer = TypedBuffer::new(self.scalar, ByteOrder::Little, bytes);
        Ok(Volume::from_buffer(&self.path(), geometry, &buffer)?)
    }

    /// The file read into a volume.
    pub fn load(&self) -> anyhow::Result<Volume> {
        self.volume(std::fs::read(self.path())?)
    }
}
