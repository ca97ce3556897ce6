//! `t2tf clip-score`: how well an image matches each of several captions under CLIP.

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::clip::{cosine, softmax_scaled};
use crate::image::{Image, ImageError};
use crate::ModelArgs;

/// Print each caption's cosine similarity to the image and CLIP's softmax probability over the
/// captions (cosines × the model's logit scale).
#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  t2tf clip-score render.png --caption \"a white skull\" \
                        --caption \"a red engine\"\n  t2tf clip-score render.png --model ./my-clip \
                        --caption \"a glowing teapot\"\n\n\
                        The image is resized (shortest side, bicubic) and centre-cropped to the \
                        model's input size as transformers' CLIPImageProcessor does."
)]
pub struct ClipScoreArgs {
    /// PNG image to score.
    pub image: PathBuf,
    /// Caption to compare with (repeat for several).
    #[arg(long = "caption", required = true, value_name = "TEXT")]
    pub captions: Vec<String>,
    #[command(flatten)]
    pub model: ModelArgs,
}

pub fn run(args: ClipScoreArgs) -> Result<()> {
    let image = Image::load_png(&args.image).map_err(|e| match e {
        // Worded as every other missing input is (`PATH: no such file`).
        ImageError::Open { path, source } if source.kind() == std::io::ErrorKind::NotFound => {
            anyhow::anyhow!("{}: no such file", path.display())
        }
        other => other.into(),
    })?;
    let clip = args
        .model
        .load_clip()
        .context("cannot load the CLIP model")?;
    let input = clip.preprocess(&image);
    let (img, _) = clip.encode_images(&[input])?;
    let captions: Vec<&str> = args.captions.iter().map(String::as_str).collect();
    let text = clip.encode_text(&captions)?;
    let sims: Vec<f32> = text.iter().map(|t| cosine(&img[0], t)).collect();
    let probs = softmax_scaled(&sims, clip.logit_scale());
    outln!("cosine   softmax  caption")?;
    for ((s, p), c) in sims.iter().zip(&probs).zip(&captions) {
        outln!("{s:>7.4}  {p:>7.4}  {c}")?;
    }
    Ok(())
}
