//! A short round of the scene-loader fuzzer (examples/fuzz_scenes.rs runs
//! a million inputs): no mutant of a shipped scene or a Mitsuba test scene
//! may panic or hang, and every refusal is one line.

mod common;

use qtrace::fuzz;
use std::time::Duration;

/// `inputs` mutants of `corpus` from `seed`: no panic, none slow, every
/// error one line; at least `each` load and `each` are refused, so the
/// mutants reach past the parsers.
fn assert_mutants_hold(corpus: &[fuzz::Corpus], seed: u64, inputs: usize, each: usize) {
    let report = fuzz::run(
        corpus,
        seed,
        inputs,
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
    assert!(report.loaded > each && report.refused > each, "{report:?}");
}

#[test]
fn mutated_scenes_load_or_refuse_in_one_line() {
    let corpus = fuzz::shipped(&common::repo("scenes")).unwrap();
    assert!(corpus.len() >= 5);
    assert_mutants_hold(&corpus, 7, 50_000, 1000);
}

/// The same for Mitsuba XML scenes and their OBJ, PLY and serialized meshes.
#[test]
fn mutated_mitsuba_scenes_load_or_refuse_in_one_line() {
    let scenes: Vec<_> = fuzz::mitsuba_scenes()
        .iter()
        .map(|p| common::repo(&p.to_string_lossy()))
        .collect();
    assert_mutants_hold(&fuzz::mitsuba(&scenes).unwrap(), 11, 3_000, 100);
}
