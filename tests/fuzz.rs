//! A short round of the scene-loader fuzzer (examples/fuzz_scenes.rs runs
//! a million inputs): no mutant of a shipped scene may panic or hang, and
//! every refusal is one line.

mod common;

use qtrace::fuzz;
use std::time::Duration;

#[test]
fn mutated_scenes_load_or_refuse_in_one_line() {
    let corpus = fuzz::shipped(&common::repo("scenes")).unwrap();
    assert!(corpus.len() >= 5);
    let report = fuzz::run(
        &corpus,
        7,
        50_000,
        fuzz::MAX_TRIANGLES,
        Duration::from_secs(2),
        &mut |_, _| None,
    );
    let what: Vec<String> = report
        .findings
        .iter()
        .map(|f| format!("input {}: {}", f.input, f.what))
        .collect();
    assert!(what.is_empty(), "{what:#?}");
    assert_eq!(report.multiline, 0);
    // The mutants reach past the parsers: some load, most are refused.
    assert!(report.loaded > 1000 && report.refused > 1000, "{report:?}");
}
