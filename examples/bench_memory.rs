//! Writes a model folder of ViT-B/32's shapes with random weights (`model.safetensors`, 605 MB,
//! the real `config.json` and `tokenizer.json` of ../shared) for measuring what `t2tf optimize`
//! costs in memory with a model of that size, e.g. under `/usr/bin/time -v`:
//!
//!     cargo run --release --features bench --example bench_memory -- DIR
//!     /usr/bin/time -v target/release/t2tf optimize VOLUME --model DIR --prompt "..." --out OUT

use std::path::{Path, PathBuf};

use safetensors::tensor::TensorView;
use safetensors::Dtype;
use t2tf::clip::{Clip, ClipConfig, RandomSource, TensorSource};

/// Records the tensors a model asks for (names and shapes), handing out zeros.
struct Recorder(std::cell::RefCell<Vec<(String, Vec<usize>)>>);

impl TensorSource for Recorder {
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, t2tf::clip::ClipError> {
        self.0.borrow_mut().push((name.to_string(), shape.to_vec()));
        Ok(vec![0.0; shape.iter().product::<usize>().max(1)])
    }
}

fn write_model(dir: &Path, shared: &Path) -> anyhow::Result<()> {
    let cfg = ClipConfig::vit_b32();
    let names = Recorder(Default::default());
    drop(Clip::from_source(cfg, &names)?);
    let random = RandomSource::new(7);
    let data: Vec<(String, Vec<usize>, Vec<u8>)> = names
        .0
        .borrow()
        .iter()
        .map(|(n, s)| {
            let v = random.tensor(n, s)?;
            Ok((
                n.clone(),
                s.clone(),
                v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            ))
        })
        .collect::<anyhow::Result<_>>()?;
    let views: Vec<(String, TensorView)> = data
        .iter()
        .map(|(n, s, b)| Ok((n.clone(), TensorView::new(Dtype::F32, s.clone(), b)?)))
        .collect::<anyhow::Result<_>>()?;
    safetensors::serialize_to_file(views, None, &dir.join("model.safetensors"))?;
    for f in ["config.json", "tokenizer.json"] {
        std::fs::copy(shared.join("data/clip").join(f), dir.join(f))?;
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let dir = PathBuf::from(
        std::env::args()
            .nth(1)
            .ok_or_else(|| anyhow::anyhow!("usage: bench_memory DIR"))?,
    );
    std::fs::create_dir_all(&dir)?;
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    write_model(&dir, &shared)?;
    println!("wrote {}", dir.display());
    Ok(())
}
