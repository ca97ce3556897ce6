//! The ground every stage of t2tf stands on: what differs between operating systems
//! ([`platform`]: the only module that calls the system directly), the memory budget sizes are checked against before
//! they are allocated ([`memory`]), output files written atomically and only as regular files
//! ([`fs`]), the kinds of error a front end words its advice from ([`error`]), RGB images
//! with PNG input and output ([`image`]: the currency between the renderer and CLIP), a fast
//! `exp` for the hot loops ([`math`]) and byte sizes for people ([`units`]).
//!
//! It depends on no other t2tf crate; every other one depends on it.

#![warn(missing_docs)]

pub mod error;
pub mod fs;
pub mod image;
pub mod input;
pub mod math;
pub mod memory;
pub mod platform;
pub mod units;
