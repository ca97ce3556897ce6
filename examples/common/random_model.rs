//! A ViT-B/32-shaped CLIP model folder with random weights, for the benchmarks that load a
//! model as a user's (`bench_refine`, `bench_memory`): speed and memory do not depend on the
//! values.

use std::path::Path;

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

/// A model folder: the real ViT-B/32 config.json and tokenizer of ../shared, random weights.
pub fn write_model(dir: &Path, shared: &Path) -> anyhow::Result<()> {
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
