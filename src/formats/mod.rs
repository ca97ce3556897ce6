//! Writing and reading transfer functions in the formats ParaView and VisIt open, and the
//! scripts that open a volume with them. Every file is written atomically.

mod atomic;

pub use atomic::{atomic_write, atomic_write_bytes};
