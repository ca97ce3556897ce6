//! Token ids equal `transformers`' CLIPTokenizerFast (truncation=True, max_length=77) on the
//! real tokenizer for several hundred varied strings (tests/fixtures/clip/tokens.json).

use std::path::Path;

use serde::Deserialize;
use t2tf::clip::ClipTokenizer;

#[derive(Deserialize)]
struct Case {
    text: String,
    ids: Vec<u32>,
}

#[derive(Deserialize)]
struct Tokens {
    cases: Vec<Case>,
}

#[test]
fn ids_match_clip_tokenizer_fast() {
    let golden: Tokens =
        serde_json::from_str(&std::fs::read_to_string("tests/fixtures/clip/tokens.json").unwrap())
            .unwrap();
    assert!(golden.cases.len() >= 300);
    let tok =
        ClipTokenizer::from_file(Path::new("../shared/data/clip/tokenizer.json"), 77).unwrap();
    let mut truncated = 0;
    for c in &golden.cases {
        let ids = tok.encode(&c.text).unwrap();
        assert_eq!(ids, c.ids, "text {:?}", c.text);
        truncated += (ids.len() == 77) as usize;
    }
    assert!(
        truncated >= 10,
        "the list should exercise truncation ({truncated} cases do)"
    );
}
