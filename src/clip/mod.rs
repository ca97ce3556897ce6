//! CLIP in Rust: tokenizer, weights, text and image encoders, image input gradient.
//! (Being written: issue 5.)
