//! The LRU brick cache: a level whose bricked copy does not fit the memory budget is rendered
//! from a bounded arena of brick slots, loaded from the level's source on demand.
//!
//! **Design.** The march reaches a brick's values through a per-brick table of slots
//! (`sample::Table`; the whole level's copy uses brick b = slot b, `sample::InPlace`, and its
//! march is compiled separately, so that path is unchanged). A view is rendered in batches of
//! consecutive 16 × 16 tiles: first every tile's rays are walked without sampling
//! (`march::bricks_touched`, the march's own block walk, so exactly the blocks it samples and
//! the bricks holding those samples, ignoring early termination), then tiles are grouped in
//! order while their bricks fit the arena together, and before each batch its missing bricks
//! are loaded into free slots, evicting the least recently used bricks that the batch does not
//! need. During a batch the arena is only read, by the rayon threads rendering its tiles.
//! Bricks that are not loaded point at slot 0, which holds zeros: a chunk of 8 samples
//! interpolates up to 7 positions past the end of a sample run and discards them, and those
//! may fall in such a brick. A tile whose bricks alone exceed the arena is an error that says
//! how to ask for more memory. A load that fails (the source cannot be read) or panics
//! forgets every brick, so no half-written slot is ever sampled.
//!
//! A brick is read with `Level::read_box` over its 9³ points (fewer at the level's far faces,
//! repeated as the whole copy repeats them) and stored with the same encoding as the whole
//! copy (`bricked::fill_brick`), so samples, and hence images and gradients, are bit-identical
//! to rendering the in-memory copy. The encoding is the level's narrow one until a loaded
//! brick holds a value it does not represent; the cache then starts over in f32 and the view
//! is rendered again from its first batch. (The whole copy decides on every value of the
//! level, the cache on the bricks it loaded: the two differ only for a level where a value
//! that 8/16 bits cannot hold lies in a brick no ray samples.)
//!
//! The march through the table is the same code with one more load per sample (the AVX2 path
//! gathers the 8 samples' slots first), so results are those of the whole copy.

use std::ops::Range;
use std::sync::Mutex;

use rayon::prelude::*;

use super::bricked::{
    fill_brick, read_box, BrickValues, Buffer, Encoding, Storage, Stored, BRICK_VALUES, PAD,
};
use crate::backend::RenderError;
use t2tf_volume::{Level, BRICK_CELLS};

/// A slot that holds no brick.
const FREE: u32 = u32::MAX;

/// Bytes of bookkeeping per brick of the level: its slot, and its mark while batches form.
const PER_BRICK: u64 = 4 + 1;
/// Bytes of bookkeeping per slot: its brick, its last use and its place in the free list.
const PER_SLOT: u64 = 4 + 8 + 4;

/// What the cache did, for tests and reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Slots for bricks (slot 0, the zero brick, not counted).
    pub slots: usize,
    /// Bricks read from the level's source.
    pub loads: u64,
    /// Bricks dropped to make room for others.
    pub evictions: u64,
    /// Bytes held: the arena and the tables (not the lists of bricks each tile of the view
    /// being rendered needs, 4 bytes per brick per tile).
    pub bytes: u64,
}

/// A level's bricks, loaded on demand into at most `budget` bytes.
pub(crate) struct BrickCache {
    /// Where bricks are read from (brick ranges not kept: the prepared level has them).
    level: Level,
    counts: [usize; 3],
    budget: u64,
    state: Mutex<State>,
}

/// The bricks of a batch, ready to sample: values by slot, and the slot of every brick.
pub(crate) struct Resident<'a> {
    pub(crate) values: BrickValues<'a>,
    pub(crate) scale: f32,
    pub(crate) slots: &'a [u32],
}

struct State {
    encoding: Encoding,
    arena: Storage,
    /// Per brick: its slot, 0 when not loaded.
    slot_of: Vec<u32>,
    /// Per brick: already in the batch being formed (all false between batches).
    marks: Vec<bool>,
    /// Per slot: its brick, or [`FREE`] (slot 0: always FREE, never handed out).
    brick_of: Vec<u32>,
    /// Per slot: the batch that last needed it.
    last_used: Vec<u64>,
    free: Vec<u32>,
    batch: u64,
    loads: u64,
    evictions: u64,
}

impl State {
    /// An empty cache of a level with `bricks` bricks in `budget` bytes.
    fn new(encoding: Encoding, bricks: usize, budget: u64) -> Result<State, RenderError> {
        let per_slot = (BRICK_VALUES * encoding.bytes()) as u64 + PER_SLOT;
        let pad = (PAD * encoding.bytes()) as u64;
        let room = budget.saturating_sub(PER_BRICK * bricks as u64 + pad) / per_slot;
        // More slots than bricks (and the zero slot) are never used.
        let slots = room.min(bricks as u64 + 1) as usize;
        if slots < 2 {
            return Err(RenderError::BrickBudget {
                needed: 1,
                slots: slots.saturating_sub(1),
                budget,
            });
        }
        // PAD: the AVX2 gathers read 4 bytes at a value's index (bricked.rs).
        let arena = Storage::zeros(encoding, slots * BRICK_VALUES + PAD);
        Ok(State {
            encoding,
            arena,
            slot_of: vec![0; bricks],
            marks: vec![false; bricks],
            brick_of: vec![FREE; slots],
            last_used: vec![0; slots],
            free: (1..slots as u32).rev().collect(),
            batch: 0,
            loads: 0,
            evictions: 0,
        })
    }

    fn slots(&self) -> usize {
        self.brick_of.len() - 1
    }

    /// Drop every brick (after a failed or interrupted load, whose slots may be half
    /// written).
    fn forget_all(&mut self) {
        self.slot_of.fill(0);
        self.marks.fill(false);
        self.brick_of.fill(FREE);
        self.last_used.fill(0);
        self.free = (1..self.brick_of.len() as u32).rev().collect();
    }

    fn bytes(&self) -> u64 {
        self.arena.values().bytes() as u64
            + PER_BRICK * self.slot_of.len() as u64
            + PER_SLOT * self.brick_of.len() as u64
    }

    fn resident(&self) -> Resident<'_> {
        Resident {
            values: self.arena.values(),
            scale: self.encoding.scale(),
            slots: &self.slot_of,
        }
    }

    /// Make every brick of `bricks` (distinct, at most [`State::slots`]) resident, evicting
    /// the least recently used of the others. `Ok(false)` when a loaded value is not
    /// represented by the encoding (nothing is usable then).
    fn ensure(
        &mut self,
        level: &Level,
        counts: [usize; 3],
        bricks: &[u32],
    ) -> Result<bool, RenderError> {
        self.batch += 1;
        let batch = self.batch;
        let mut missing = Vec::new();
        for &b in bricks {
            match self.slot_of[b as usize] {
                0 => missing.push(b),
                s => self.last_used[s as usize] = batch,
            }
        }
        if missing.len() > self.free.len() {
            let mut victims: Vec<u32> = (1..self.brick_of.len() as u32)
                .filter(|&s| {
                    self.brick_of[s as usize] != FREE && self.last_used[s as usize] < batch
                })
                .collect();
            victims.sort_unstable_by_key(|&s| (self.last_used[s as usize], s));
            for &s in &victims[..missing.len() - self.free.len()] {
                let b = std::mem::replace(&mut self.brick_of[s as usize], FREE);
                self.slot_of[b as usize] = 0;
                self.free.push(s);
                self.evictions += 1;
            }
        }
        let mut fresh: Vec<(u32, u32)> = missing
            .iter()
            .map(|&b| {
                let s = self.free.pop().expect("a batch's bricks fit the arena");
                self.slot_of[b as usize] = s;
                self.brick_of[s as usize] = b;
                self.last_used[s as usize] = batch;
                (s, b)
            })
            .collect();
        fresh.sort_unstable();
        self.loads += fresh.len() as u64;
        let e = self.encoding;
        let loaded = match &mut self.arena {
            Storage::U8(a) => load(a, &fresh, e, level, counts),
            Storage::U16(a) => load(a, &fresh, e, level, counts),
            Storage::F32(a) => load(a, &fresh, e, level, counts),
        };
        if loaded.is_err() {
            self.forget_all();
        }
        loaded
    }
}

/// Read bricks `fresh` (slot, brick; sorted by slot) of `level` into their slots of `arena`,
/// in parallel. Whether `encoding` represented every value.
fn load<T: Stored>(
    arena: &mut Buffer<T>,
    fresh: &[(u32, u32)],
    encoding: Encoding,
    level: &Level,
    c: [usize; 3],
) -> Result<bool, RenderError> {
    let mut jobs = Vec::with_capacity(fresh.len());
    let mut next = fresh.iter().peekable();
    for (s, dst) in arena
        .as_mut_slice()
        .chunks_exact_mut(BRICK_VALUES)
        .enumerate()
    {
        if let Some(&&(slot, b)) = next.peek() {
            if slot as usize == s {
                jobs.push((dst, b as usize));
                next.next();
            }
        }
    }
    // In source order, a chunk at a time: the pages of a memory-mapped level 0 that a chunk
    // touched are released before the next (`Level::release_source`). A brick's 81 rows may
    // each sit on its own page, so without this a batch of a file larger than memory could
    // keep most of the file's pages counted as this process's memory.
    jobs.sort_unstable_by_key(|&(_, b)| b);
    for chunk in jobs.chunks_mut(RELEASE_EVERY) {
        let exact = load_chunk(chunk, encoding, level, c)?;
        level.release_source();
        if !exact {
            return Ok(false); // the caller starts over in f32
        }
    }
    Ok(true)
}

/// Bricks loaded between two releases of the source's pages: at most 81 pages each, so about
/// 330 MiB of pages at the worst.
const RELEASE_EVERY: usize = 1024;

/// Read `jobs` (destination, brick) of `level`, in parallel. Whether `encoding` represented
/// every value.
fn load_chunk<T: Stored>(
    jobs: &mut [(&mut [T], usize)],
    encoding: Encoding,
    level: &Level,
    c: [usize; 3],
) -> Result<bool, RenderError> {
    let dims = level.dims;
    jobs.par_iter_mut()
        .map(|(dst, b)| {
            let b = *b;
            let origin = [b % c[0], (b / c[0]) % c[1], b / (c[0] * c[1])].map(|x| x * BRICK_CELLS);
            let hi: [usize; 3] =
                std::array::from_fn(|ax| (origin[ax] + BRICK_CELLS + 1).min(dims[ax]));
            let n: [usize; 3] = std::array::from_fn(|ax| hi[ax] - origin[ax]);
            let mut boxed = [0.0f32; BRICK_VALUES];
            let boxed = &mut boxed[..n[0] * n[1] * n[2]];
            read_box(level, origin, hi, boxed)?;
            Ok(fill_brick(
                dst,
                (origin, dims),
                boxed,
                (origin, [n[0], n[1]]),
                encoding,
            ))
        })
        .try_reduce(|| true, |a, b| Ok(a && b))
}

impl BrickCache {
    /// A cache of `level` (brick counts `counts`) stored as `encoding` in `budget` bytes.
    pub(crate) fn new(
        level: &Level,
        counts: [usize; 3],
        encoding: Encoding,
        budget: u64,
    ) -> Result<BrickCache, RenderError> {
        let bricks: usize = counts.iter().product();
        if bricks >= FREE as usize {
            // Slot tables hold brick numbers in 32 bits.
            return Err(RenderError::BrickBudget {
                needed: bricks,
                slots: 0,
                budget,
            });
        }
        let state = State::new(encoding, bricks, budget)?;
        let mut level = level.clone();
        level.bricks.min = Vec::new();
        level.bricks.max = Vec::new();
        level.bricks.uniform = Vec::new();
        Ok(BrickCache {
            level,
            counts,
            budget,
            state: Mutex::new(state),
        })
    }

    /// What the cache holds and has done.
    pub(crate) fn stats(&self) -> CacheStats {
        let s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        CacheStats {
            slots: s.slots(),
            loads: s.loads,
            evictions: s.evictions,
            bytes: s.bytes(),
        }
    }

    /// The stored kind of values (the arena's slice, empty outside a batch).
    pub(crate) fn kind(&self) -> BrickValues<'static> {
        match self
            .state
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .encoding
        {
            Encoding::F32 => BrickValues::F32(&[]),
            e if e.bytes() == 1 => BrickValues::U8(&[]),
            _ => BrickValues::U16(&[]),
        }
    }

    /// Render one view in batches: `needs` lists, per tile in order, the bricks its rays read
    /// (sorted, distinct; given the resident bricks for the grid's shape, values unused);
    /// `batch` renders a range of tiles from the resident bricks. The results, in tile order.
    /// Views of one cache run one at a time.
    pub(crate) fn run<R: Send>(
        &self,
        needs: impl FnOnce(Resident) -> Vec<Vec<u32>>,
        mut batch: impl FnMut(Resident, Range<usize>) -> Vec<R>,
    ) -> Result<Vec<R>, RenderError> {
        let mut state = self.state.lock().unwrap_or_else(|poisoned| {
            // A panic while bricks were loading may have left slots half written.
            let mut state = poisoned.into_inner();
            state.forget_all();
            state
        });
        self.state.clear_poison();
        let needs = needs(state.resident());
        'again: loop {
            let mut out = Vec::with_capacity(needs.len());
            let mut start = 0;
            while start < needs.len() {
                // The longest run of tiles from `start` whose bricks fit together.
                let mut bricks: Vec<u32> = Vec::new();
                let mut end = start;
                while end < needs.len() {
                    let new = needs[end]
                        .iter()
                        .filter(|&&b| !state.marks[b as usize])
                        .count();
                    if bricks.len() + new > state.slots() {
                        break;
                    }
                    for &b in &needs[end] {
                        if !std::mem::replace(&mut state.marks[b as usize], true) {
                            bricks.push(b);
                        }
                    }
                    end += 1;
                }
                if end == start {
                    return Err(RenderError::BrickBudget {
                        needed: needs[start].len(),
                        slots: state.slots(),
                        budget: self.budget,
                    });
                }
                for &b in &bricks {
                    state.marks[b as usize] = false;
                }
                if !state.ensure(&self.level, self.counts, &bricks)? {
                    // A value the narrow encoding does not hold: start over in f32.
                    let bricks = state.slot_of.len();
                    state.arena = Storage::zeros(Encoding::F32, 0); // freed before the new one
                    *state = State::new(Encoding::F32, bricks, self.budget)?;
                    continue 'again;
                }
                out.extend(batch(state.resident(), start..end));
                start = end;
            }
            return Ok(out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::volume_of;
    use super::*;
    use crate::Backend;

    /// The least recently used brick that the batch does not need is the one evicted, and a
    /// loaded brick holds what the whole copy holds.
    #[test]
    fn evicts_the_least_recently_used_brick() {
        // 33 × 2 × 2 points: 4 bricks along x.
        let v = volume_of([33, 2, 2], |i, j, k| ((i * 7 + j * 3 + k) % 11) as f64);
        let level = &v.levels[0];
        let counts = level.bricks.counts;
        assert_eq!(counts, [4, 1, 1]);
        let e = Encoding::of(level.narrow());
        let per_slot = (BRICK_VALUES * e.bytes()) as u64 + PER_SLOT;
        // The zero slot and two bricks.
        let budget = 4 * PER_BRICK + 3 * per_slot + (PAD * e.bytes()) as u64;
        let mut s = State::new(e, 4, budget).unwrap();
        assert_eq!(s.slots(), 2);
        assert!(s.bytes() <= budget);
        for batch in [&[0u32][..], &[1], &[0], &[2]] {
            assert!(s.ensure(level, counts, batch).unwrap());
        }
        assert_eq!((s.loads, s.evictions), (3, 1));
        assert_eq!(s.slot_of[1], 0, "brick 1 was the least recently used");
        assert!(s.slot_of[0] != 0 && s.slot_of[2] != 0);
        // Brick 2's values are the whole copy's.
        let whole = super::super::CpuBackend::default().prepare(&v, 0).unwrap();
        let (BrickValues::F32(all), BrickValues::F32(arena)) = (whole.values(), s.arena.values())
        else {
            panic!("a float volume is stored in f32")
        };
        let slot = s.slot_of[2] as usize;
        assert_eq!(
            arena[slot * BRICK_VALUES..][..BRICK_VALUES],
            all[2 * BRICK_VALUES..][..BRICK_VALUES]
        );
        // Slot 0 stays zero.
        assert!(arena[..BRICK_VALUES].iter().all(|&x| x == 0.0));
        // Two bricks in one batch may not evict each other.
        assert!(s.ensure(level, counts, &[3, 1]).unwrap());
        assert!(s.slot_of[3] != 0 && s.slot_of[1] != 0);
        assert_eq!(s.evictions, 3);
    }
}
