//! The converged campaign's status tables in `docs/results/experiments.md` are written by
//! hand as trainings finish; this test holds them to the committed result files, so that
//! they cannot drift: one row per finished training (no more, no fewer), and each row's
//! iterations, network used, validation error, last-tenth change and training time as its
//! `train-*.json` records them.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

use std::path::{Path, PathBuf};

use pvrnn_experiment::run::{TrainResult, read_train_result};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The body rows of the markdown table whose header line starts with `header`, each split
/// into its trimmed cells.
fn table(doc: &str, header: &str) -> Vec<Vec<String>> {
    let mut lines = doc.lines().skip_while(|l| !l.starts_with(header));
    assert!(
        lines.next().is_some(),
        "docs/results/experiments.md has no table headed `{header}`"
    );
    lines
        .skip(1) // the |---| line
        .take_while(|l| l.starts_with('|'))
        .map(|l| {
            l.trim_matches('|')
                .split('|')
                .map(|cell| cell.trim().to_string())
                .collect()
        })
        .collect()
}

/// The leading number of a cell ("16,000", "0.006221 (2k-16k: ...)", "−3.1%",
/// "4,742 s on 2 threads"), with the typographic minus.
fn leading_number(cell: &str) -> f64 {
    let text: String = cell
        .replace('−', "-")
        .replace(',', "")
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.' || *c == '-')
        .collect();
    text.parse()
        .unwrap_or_else(|_| panic!("no number at the start of `{cell}`"))
}

/// Checks one row (`cells[1..]`: stopped at, network used, validation error, last-tenth
/// change, training time) against its result, as the table rounds them.
fn check_row(cells: &[String], result: &TrainResult) {
    let what = &cells[0];
    assert_eq!(
        leading_number(&cells[1]),
        result.iterations as f64,
        "{what}: stopped at"
    );
    let used = result
        .network_iteration
        .expect("a converged training names its network");
    assert_eq!(
        leading_number(&cells[2]),
        used as f64,
        "{what}: network used"
    );
    let validation = result
        .validations
        .iter()
        .find(|v| v.iteration == used)
        .unwrap_or_else(|| panic!("{what}: no validation at iteration {used}"));
    let error = leading_number(&cells[3]);
    assert!(
        (error - validation.recon_vision_top).abs() <= 0.5e-6,
        "{what}: validation error {error} in the table, {} in the result",
        validation.recon_vision_top
    );
    let change = 100.0 * result.last_tenth_change.expect("a last-tenth change");
    assert!(
        (leading_number(&cells[4]) - change).abs() <= 0.05 + 1e-9,
        "{what}: last-tenth change {} in the table, {change:.2}% in the result",
        cells[4]
    );
    assert!(
        (leading_number(&cells[5]) - result.seconds).abs() <= 0.5 + 1e-9,
        "{what}: training time {} in the table, {:.1} s in the result",
        cells[5],
        result.seconds
    );
}

/// The training results committed in `dir` (`results/train-*.json`), by job name.
fn results(dir: &str) -> Vec<TrainResult> {
    let folder = repo().join(dir).join("results");
    let mut found: Vec<TrainResult> = std::fs::read_dir(&folder)
        .unwrap_or_else(|e| panic!("{}: {e}", folder.display()))
        .map(|entry| entry.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.starts_with("train-") && name.ends_with(".json")
        })
        .map(|p| read_train_result(&p).unwrap())
        .collect();
    found.sort_by(|a, b| a.job.cmp(&b.job));
    found
}

fn doc() -> String {
    std::fs::read_to_string(repo().join("docs/results/experiments.md")).unwrap()
}

/// The table headed `header` against the trainings of `dir`: as many rows as results, and
/// each result's row (the one whose first cell starts with `row_start(result)`) as it.
fn check_table(header: &str, dir: &str, row_start: impl Fn(&TrainResult) -> String) {
    let rows = table(&doc(), header);
    let results = results(dir);
    assert_eq!(
        rows.len(),
        results.len(),
        "the table `{header}` has {} rows, and {} trainings are done: one row each",
        rows.len(),
        results.len()
    );
    for result in &results {
        let start = row_start(result);
        let row = rows
            .iter()
            .find(|r| r[0].starts_with(&start))
            .unwrap_or_else(|| panic!("no row `{start}...` for {}", result.job));
        check_row(row, result);
    }
}

#[test]
fn the_shared_networks_table_matches_their_results() {
    // "0 (seed 0)"
    check_table(
        "| network | stopped at | network used |",
        "docs/results/converged/hierarchy",
        |result| format!("{} ", result.network),
    );
}

#[test]
fn the_interference_table_has_a_row_for_every_finished_training() {
    // "repositioning 9 + wiping 3, net 1 (seed 1)"
    check_table(
        "| training | stopped at | network used |",
        "docs/results/converged/interference",
        |result| format!("{}, net {} ", result.condition, result.network),
    );
}
