//! The main job through the library API: load a volume and a CLIP model, optimize a transfer
//! function for a prompt with the paper's defaults, and write the output set `t2tf optimize`
//! writes (TF files, scripts, tf.png, preview.png, report.json).
//!
//! `cargo run --release --example library -- VOLUME PROMPT MODEL_DIR TOKENIZER OUT_DIR`
//! e.g. with the test model, offline:
//! `cargo run --release --example library -- ../shared/data/volumes/neghip_64x64x64_uint8.raw
//!  "a molecule" tests/fixtures/clip/quick_gelu ../shared/data/clip/tokenizer.json neghip-tf`

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use t2tf::pipeline::{self, Event, Job, Model, ModelOptions, Target};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [volume, prompt, model, tokenizer, out] = args.as_slice() else {
        return Err("usage: library VOLUME PROMPT MODEL_DIR TOKENIZER OUT_DIR".into());
    };
    let volume = pipeline::load_volume(Path::new(volume), &Default::default())?;
    let model = Model::load(&ModelOptions {
        tokenizer: Some(PathBuf::from(tokenizer)),
        ..ModelOptions::new(model.as_str())
    })?;
    let job = Job::new(Target::Prompt(prompt.clone())).validate()?;
    let result = pipeline::optimize(&volume, &model, &job, &mut |event| {
        match event {
            Event::Phase(what) => eprintln!("{what}"),
            Event::Step { step, total, log } if step % 50 == 0 || step == total => {
                eprintln!("step {step}/{total}: loss {:.4}", log.total)
            }
            Event::Warning(w) => eprintln!("warning: {w}"),
            Event::Step { .. } => {}
        }
        ControlFlow::Continue(())
    })?;
    let out = Path::new(out);
    let name = out.file_name().map_or("tf".into(), |n| n.to_string_lossy());
    let report = result.write(out, &name)?;
    println!("wrote {} to {}", report.outputs.join(", "), out.display());
    Ok(())
}
