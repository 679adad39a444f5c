//! A short round of the scene-loader fuzzer (examples/fuzz_scenes.rs runs
//! a million inputs): no mutant of a shipped scene or a Mitsuba test scene
//! may panic or hang, and every refusal is one line.

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

/// The same for Mitsuba XML scenes and their OBJ, PLY and serialized meshes.
#[test]
fn mutated_mitsuba_scenes_load_or_refuse_in_one_line() {
    let scenes: Vec<_> = fuzz::mitsuba_scenes()
        .iter()
        .map(|p| common::repo(&p.to_string_lossy()))
        .collect();
    let corpus = fuzz::mitsuba(&scenes).unwrap();
    let report = fuzz::run(
        &corpus,
        11,
        3_000,
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
    assert_eq!(report.multiline, 0, "{:?}", report.multiline_example);
    assert!(report.loaded > 100 && report.refused > 100, "{report:?}");
}
