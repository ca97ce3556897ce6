//! Replays the fuzzer's committed corpus (tests/fuzz_corpus/TARGET/, written by
//! `cargo run --release --example fuzz -- --all --save-corpus`) and every target's seeds:
//! each input must give `Ok` or an error, never a panic. The inputs are the distinct
//! behaviours the fuzzer found, so this keeps every parser's odd corners covered in CI. The
//! generated seeds (presets of 10⁶ points in every format) must also end in the start's
//! point limit, read and simplified in linear time (a quadratic pass would not finish).

#[path = "../../examples/fuzz/targets.rs"]
#[allow(dead_code)]
mod targets;

use std::path::Path;

#[test]
fn every_corpus_input_is_ok_or_an_error_never_a_panic() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let work = tempfile::tempdir().unwrap();
    let mut replayed = 0;
    for t in targets::TARGETS {
        let mut inputs: Vec<std::path::PathBuf> = t.seeds.iter().map(|s| root.join(s)).collect();
        if let Ok(entries) = std::fs::read_dir(targets::corpus_dir(root, t)) {
            inputs.extend(entries.flatten().map(|e| e.path()));
        }
        let file = work.path().join(t.file_name);
        for input in inputs {
            std::fs::copy(&input, &file).unwrap();
            let outcome = std::panic::catch_unwind(|| (t.run)(&file));
            assert!(outcome.is_ok(), "{}: {} panicked", t.name, input.display());
            replayed += 1;
        }
        if let Some(make) = t.generated {
            std::fs::write(&file, make()).unwrap();
            let outcome = std::panic::catch_unwind(|| (t.run)(&file));
            let Ok(Err(e)) = outcome else {
                panic!("{}: the generated input gave {outcome:?}", t.name);
            };
            assert!(
                e.contains("colour and opacity points") && e.contains("a start takes at most 4096"),
                "{}: {e}",
                t.name
            );
            replayed += 1;
        }
    }
    eprintln!("replayed {replayed} inputs");
    assert!(replayed >= targets::TARGETS.len());
}
