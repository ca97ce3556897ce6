//! CLIP's byte-level BPE tokenizer via the `tokenizers` crate and a `tokenizer.json`
//! (what `transformers`' `CLIPTokenizerFast` wraps): lower-casing and whitespace clean-up,
//! `<|startoftext|>` … `<|endoftext|>` around the text, truncation to the context length
//! (77) keeping both special tokens, as `CLIPTokenizerFast(text, truncation=True,
//! max_length=77)` does. No padding: the text encoder runs each caption only up to its
//! end-of-text token.

use std::path::{Path, PathBuf};

use tokenizers::{Tokenizer, TruncationParams};

use super::ClipError;

/// CLIP's tokenizer, from a `tokenizer.json`.
pub struct ClipTokenizer {
    tok: Tokenizer,
    path: PathBuf,
}

impl ClipTokenizer {
    /// Load `tokenizer.json`, truncating encodings to `context` tokens.
    pub fn from_file(path: &Path, context: usize) -> Result<ClipTokenizer, ClipError> {
        let err = |msg: String| ClipError::Tokenizer {
            path: path.to_path_buf(),
            msg,
        };
        if !path.exists() {
            return Err(err("file not found".into()));
        }
        let bytes = t2tf_core::input::read(path).map_err(|e| err(e.to_string()))?;
        let mut tok =
            Tokenizer::from_bytes(&bytes).map_err(|e| err(format!("cannot parse: {e}")))?;
        tok.with_truncation(Some(TruncationParams {
            max_length: context,
            ..Default::default()
        }))
        .map_err(|e| err(format!("cannot set truncation: {e}")))?;
        tok.with_padding(None);
        Ok(ClipTokenizer {
            tok,
            path: path.to_path_buf(),
        })
    }

    /// Token ids of `text`, special tokens included, at most `context` of them.
    pub fn encode(&self, text: &str) -> Result<Vec<u32>, ClipError> {
        let enc = self
            .tok
            .encode(text, true)
            .map_err(|e| ClipError::Tokenizer {
                path: self.path.clone(),
                msg: format!("cannot encode {text:?}: {e}"),
            })?;
        Ok(enc.get_ids().to_vec())
    }

    /// Id of `<|endoftext|>`, if the vocabulary has it.
    pub fn eos_id(&self) -> Option<u32> {
        self.tok.token_to_id("<|endoftext|>")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_ids_and_truncation() {
        let t = ClipTokenizer::from_file(
            Path::new(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../../shared/data/clip/tokenizer.json"
            )),
            77,
        )
        .unwrap();
        assert_eq!(
            t.encode("a potted tree").unwrap(),
            vec![49406, 320, 48581, 2677, 49407]
        );
        assert_eq!(t.encode("").unwrap(), vec![49406, 49407]);
        let long = t.encode(&"word ".repeat(200)).unwrap();
        assert_eq!(long.len(), 77);
        assert_eq!((long[0], long[76]), (49406, 49407));
        assert_eq!(t.eos_id(), Some(49407));
    }

    #[test]
    fn missing_file_is_named() {
        let e = ClipTokenizer::from_file(Path::new("nowhere/tokenizer.json"), 77)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("nowhere/tokenizer.json") && e.contains("not found"),
            "{e}"
        );
    }
}
