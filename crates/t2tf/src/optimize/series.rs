//! The steps of a time series as the renderer reads them: loaded on demand, normalized over
//! the series' range, a few recent ones kept.
//!
//! The optimizer's schedule (`schedule::assign_times`) lets consecutive steps share all their
//! views' time steps but one, so a cache of `views + 1` volumes makes a run load about one
//! time step per optimizer step, and memory holds that many volumes (their coarse levels and
//! the renderer's copies of the levels drawn) however long the series is. A volume dropped
//! from the cache takes the renderer's copies of its levels with it (the backend keys them
//! by the level's allocation).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use crate::volume::{
    ReadOptions, Series, SeriesStats, SeriesStep, Volume, VolumeError, HISTOGRAM_BINS,
};

/// A series opened for a run: its steps, its statistics, and the cache of loaded steps (or
/// every step, for a series held in memory).
#[derive(Debug)]
pub struct SeriesSteps {
    series: Arc<Series>,
    stats: SeriesStats,
    opts: ReadOptions,
    capacity: usize,
    cache: Mutex<VecDeque<(usize, Arc<Volume>)>>,
    held: Vec<Arc<Volume>>,
    loads: AtomicUsize,
    representative: OnceLock<Volume>,
}

impl SeriesSteps {
    /// Open `series` for a run: its statistics streamed step by step (`on_step(i)` as step
    /// `i` is read), steps read with `opts`, at most `capacity` (≥ 1) kept loaded.
    pub fn open(
        series: Series,
        opts: ReadOptions,
        capacity: usize,
        on_step: &mut dyn FnMut(usize),
    ) -> Result<SeriesSteps, VolumeError> {
        let stats = series.scan(&opts, on_step)?;
        Ok(SeriesSteps {
            series: Arc::new(series),
            stats,
            opts,
            capacity: capacity.max(1),
            cache: Mutex::new(VecDeque::new()),
            held: Vec::new(),
            loads: AtomicUsize::new(0),
            representative: OnceLock::new(),
        })
    }

    /// A series held in memory: `steps` (time, volume), every volume normalized over the
    /// same range (e.g. `Volume::from_shared_over` with the range of all of them), in
    /// increasing time. Each step is named `name` and its index in errors and the report.
    pub fn from_volumes(name: &str, steps: Vec<(f64, Volume)>) -> Result<SeriesSteps, VolumeError> {
        let named = |i: usize| std::path::PathBuf::from(format!("{name} (time step {i})"));
        let Some((_, first)) = steps.first() else {
            return Err(VolumeError::file(
                &named(0),
                "a series needs at least one step",
            ));
        };
        let (norm_range, dims) = (first.norm_range, first.geometry.dims);
        let mut histogram = vec![0u64; HISTOGRAM_BINS];
        for (i, (t, v)) in steps.iter().enumerate() {
            let why = if v.norm_range != norm_range {
                "is not normalized over the same range as the first step"
            } else if v.geometry.dims != dims {
                "differs in size from the first step"
            } else if !t.is_finite() || (i > 0 && *t <= steps[i - 1].0) {
                "has a time that is not finite or not after the previous step's"
            } else {
                ""
            };
            if !why.is_empty() {
                return Err(VolumeError::file(&named(i), why));
            }
            for (h, k) in histogram.iter_mut().zip(&v.histogram) {
                *h += k;
            }
        }
        let step_ranges: Vec<[f64; 2]> = steps.iter().map(|(_, v)| v.range).collect();
        let non_finite = steps.iter().map(|(_, v)| v.non_finite).sum();
        let range = step_ranges
            .iter()
            .fold([f64::INFINITY, f64::NEG_INFINITY], |r, s| {
                [r[0].min(s[0]), r[1].max(s[1])]
            });
        let series = Arc::new(Series {
            collection: None,
            steps: (0..steps.len())
                .map(|i| SeriesStep {
                    time: steps[i].0,
                    path: named(i),
                })
                .collect(),
            total_steps: steps.len(),
        });
        let held = steps
            .into_iter()
            .map(|(_, mut v)| {
                v.series = Some(series.clone());
                Arc::new(v)
            })
            .collect();
        Ok(SeriesSteps {
            stats: SeriesStats {
                range,
                norm_range,
                non_finite,
                step_ranges,
                histogram,
            },
            series,
            opts: ReadOptions::default(),
            capacity: 1,
            cache: Mutex::new(VecDeque::new()),
            held,
            loads: AtomicUsize::new(0),
            representative: OnceLock::new(),
        })
    }

    /// The series (steps used, collection).
    pub fn series(&self) -> &Arc<Series> {
        &self.series
    }

    /// Statistics over every step used.
    pub fn stats(&self) -> &SeriesStats {
        &self.stats
    }

    /// Steps used.
    pub fn len(&self) -> usize {
        self.series.steps.len()
    }

    /// Whether the series has no step (never: a series has at least one).
    pub fn is_empty(&self) -> bool {
        self.series.steps.is_empty()
    }

    /// Whether the steps are held in memory ([`SeriesSteps::from_volumes`]), not read from
    /// files.
    pub fn in_memory(&self) -> bool {
        !self.held.is_empty()
    }

    /// Times a step was read from its file (cache misses).
    pub fn loads(&self) -> usize {
        self.loads.load(Ordering::Relaxed)
    }

    /// Step `t`, normalized over the series' range: from the cache, else read and cached
    /// (the least recently used step leaves).
    pub fn step(&self, t: usize) -> Result<Arc<Volume>, VolumeError> {
        if let Some(v) = self.held.get(t) {
            return Ok(v.clone());
        }
        {
            let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(k) = cache.iter().position(|(i, _)| *i == t) {
                let hit = cache.remove(k).expect("found above");
                cache.push_back(hit.clone());
                return Ok(hit.1);
            }
        }
        let volume = Arc::new(
            self.series
                .load_step(t, self.stats.norm_range, &self.opts)?,
        );
        self.loads.fetch_add(1, Ordering::Relaxed);
        let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        if !cache.iter().any(|(i, _)| *i == t) {
            while cache.len() >= self.capacity {
                cache.pop_front();
            }
            cache.push_back((t, volume.clone()));
        }
        Ok(volume)
    }

    /// The volume that stands for the whole series where one is needed (the data range of
    /// the exports, the histogram of the initialization, the locks' checks, the geometry of
    /// the scripts): the first step, with the series' range and histogram.
    pub fn representative(&self) -> Result<&Volume, VolumeError> {
        if let Some(v) = self.representative.get() {
            return Ok(v);
        }
        let mut v = (*self.step(0)?).clone();
        v.range = self.stats.range;
        v.non_finite = self.stats.non_finite;
        v.histogram = self.stats.histogram.clone();
        Ok(self.representative.get_or_init(|| v))
    }
}
