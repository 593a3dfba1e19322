//! The results' index (`docs/results/index.md`: every training's table, generated from the
//! result files) regenerated and compared with the committed one; and the prose of
//! `docs/results/experiments.md` that restates the same files held to them (how
//! many of the plan's trainings are done and remain, and by how much every finished
//! network beats the best baseline its validations recorded, per primary task); and
//! `docs/experiments.md`'s count and time range of the same trainings.

use std::path::{Path, PathBuf};

use pvrnn_experiment::run::{TrainResult, read_train_result};

/// The converged interference campaign's folder.
const INTERFERENCE: &str = "docs/results/converged/interference";

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
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
    read_doc("docs/results/experiments.md")
}

/// The leading number of a cell ("16,000", "0.006221 (2k-16k: ...)", "−3.1%"), with the
/// typographic minus.
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

fn read_doc(path: &str) -> String {
    std::fs::read_to_string(repo().join(path)).unwrap_or_else(|e| panic!("{path}: {e}"))
}

#[test]
fn the_results_index_is_what_the_result_files_give() {
    let fresh = pvrnn_experiment::index::index(&repo().join("docs/results")).unwrap();
    let committed = read_doc("docs/results/index.md");
    assert!(
        committed == fresh,
        "docs/results/index.md is not what the result files give: run `pvrnn report index docs/results --out docs/results/index.md`"
    );
}

/// The document with every run of white space (line breaks included) made one space, so
/// that a phrase matches wherever the text was wrapped.
fn flat_doc() -> String {
    flat(&doc())
}

fn flat(text: &str) -> String {
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// The number written right before each occurrence of `phrase` (`"10 of its 40"`: 10 for
/// `" of its 40"`); fails if the phrase is not there.
fn numbers_before(doc: &str, phrase: &str) -> Vec<usize> {
    let found: Vec<usize> = doc
        .match_indices(phrase)
        .map(|(at, _)| {
            let digits: String = doc[..at]
                .chars()
                .rev()
                .take_while(char::is_ascii_digit)
                .collect::<Vec<_>>()
                .into_iter()
                .rev()
                .collect();
            digits
                .parse()
                .unwrap_or_else(|_| panic!("no number right before `{phrase}`"))
        })
        .collect();
    assert!(!found.is_empty(), "the document no longer says `{phrase}`");
    found
}

/// The interference plan's trainings (`plan.json`'s jobs of kind `train`).
fn planned_trainings(dir: &str) -> usize {
    let text = std::fs::read_to_string(repo().join(dir).join("plan.json")).unwrap();
    let plan: serde_json::Value = serde_json::from_str(&text).unwrap();
    plan["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|job| job["kind"] == "train")
        .count()
}

#[test]
fn the_interference_counts_in_the_prose_match_the_results() {
    let dir = INTERFERENCE;
    let done = results(dir).len();
    let planned = planned_trainings(dir);
    let doc = flat_doc();
    for (phrase, expected) in [
        (format!(" of its {planned} trainings are done"), done),
        (format!(" of {planned} done)"), done),
    ] {
        for number in numbers_before(&doc, &phrase) {
            assert_eq!(
                number, expected,
                "`{number}{phrase}`: {done} of {planned} are done"
            );
        }
    }
    let remain = planned - done;
    let noun = if remain == 1 { "training" } else { "trainings" };
    let stated = format!("**What remains, and where it runs.** {remain} {noun}:");
    assert!(
        doc.contains(&stated),
        "the status should say `{stated}` ({done} of {planned} are done)"
    );
}

/// The interference campaign's primary tasks: a training's condition opens with its own
/// ("repositioning 9 + wiping 3"), and it is validated on that task's held-out sequences.
const PRIMARY_TASKS: [&str; 2] = ["repositioning", "wiping"];

#[test]
fn every_finished_interference_network_is_stated_against_the_best_baseline() {
    // Per primary task with a finished training, a paragraph: "The baselines on the same 12
    // held-out repositioning sequences (1 trial each): ... upsampling with the mean image's
    // detail 0.004588, ... All 10 networks beat all three baselines (by 19-25% the best of
    // them)", or where some do not: "3 of the 5 networks beat all three baselines (by 2-4%
    // the best of them); the other 2 are 10-12% above upsampling with the mean image's
    // detail" ("0 of the 1 networks ...; the other 1 is 62% above ...").
    let doc = doc();
    for task in PRIMARY_TASKS {
        let results: Vec<TrainResult> = results(INTERFERENCE)
            .into_iter()
            .filter(|r| r.condition.starts_with(&format!("{task} ")))
            .collect();
        if results.is_empty() {
            continue;
        }
        let opening = format!("The baselines on the same 12 held-out {task} sequences");
        let paragraph = flat(
            doc.split("\n\n")
                .find(|p| p.starts_with(&opening))
                .unwrap_or_else(|| panic!("no paragraph `{opening}...`")),
        );
        // The stated best baseline is the validations' (every row records the baselines).
        let detail = "upsampling with the mean image's detail ";
        let best = leading_number(&paragraph[paragraph.find(detail).unwrap() + detail.len()..]);
        for result in &results {
            for row in &result.validations {
                let recorded = [row.upsample, row.upsample_detail, row.mean]
                    .into_iter()
                    .flatten()
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    (recorded - best).abs() <= 0.5e-6,
                    "{}: best baseline {recorded} in its validations, {best} stated",
                    result.job
                );
            }
        }
        // Percent below the best baseline, per network (negative: above it).
        let margins: Vec<f64> = results
            .iter()
            .map(|result| {
                100.0
                    * (1.0
                        - result
                            .gate()
                            .and_then(|g| g.checks.iter().find(|c| c.measure == "vision")?.model)
                            .expect("a validation of the network used")
                            / best)
            })
            .collect();
        let beating: Vec<f64> = margins.iter().copied().filter(|&m| m > 0.0).collect();
        let above: Vec<f64> = margins.iter().map(|m| -m).filter(|&m| m >= 0.0).collect();
        let all = results.len();
        // "18-25%", or "62%" for one value.
        let stated_range = |text: &str| {
            let range = &text[..text.find('%').unwrap()];
            match range.split_once('-') {
                Some((low, high)) => (leading_number(low), leading_number(high)),
                None => (leading_number(range), leading_number(range)),
            }
        };
        let rounded_range = |values: &[f64]| {
            let low = values.iter().copied().fold(f64::INFINITY, f64::min);
            let high = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (low.round(), high.round())
        };
        if above.is_empty() {
            let count = numbers_before(&paragraph, " networks beat all three baselines");
            assert_eq!(count, [all], "{task}: the finished networks");
            assert!(
                paragraph.contains(&format!("All {all} networks beat all three baselines")),
                "{task}: every network beats the best baseline"
            );
        } else {
            let phrase = format!(" of the {all} networks beat all three baselines");
            let count = numbers_before(&paragraph, &phrase);
            assert_eq!(
                count,
                [beating.len()],
                "{task}: the networks that beat the best baseline ({best})"
            );
            let verb = if above.len() == 1 { "is" } else { "are" };
            let others = format!("the other {} {verb} ", above.len());
            let at = paragraph
                .find(&others)
                .unwrap_or_else(|| panic!("{task}: no `{others}...`"));
            let range = stated_range(&paragraph[at + others.len()..]);
            assert_eq!(
                range,
                rounded_range(&above),
                "{task}: the networks above the best baseline, percent"
            );
            assert!(
                paragraph[at..].contains("% above upsampling with the mean image's detail"),
                "{task}: what the others are above"
            );
        }
        if !beating.is_empty() {
            let range = &paragraph[paragraph.find("(by ").unwrap() + 4..];
            assert_eq!(
                stated_range(range),
                rounded_range(&beating),
                "the {task} networks beat the best baseline by {:?}%",
                rounded_range(&beating)
            );
        }
    }
}

/// Each `(low-high unit` range written right before `unit` (as in "(3,296-22,896 s"),
/// the two numbers parsed; fails if there is none.
fn ranges_before(doc: &str, unit: &str) -> Vec<(f64, f64)> {
    let found: Vec<(f64, f64)> = doc
        .match_indices(unit)
        .filter_map(|(at, _)| {
            let start = doc[..at].rfind(['(', ' '])?;
            let (low, high) = doc[start + 1..at].split_once('-')?;
            let number = |s: &str| s.replace(',', "").parse::<f64>().ok();
            Some((number(low)?, number(high)?))
        })
        .collect();
    assert!(
        !found.is_empty(),
        "no `low-high{unit}` range in the document"
    );
    found
}

#[test]
fn the_plan_document_states_the_campaign_as_its_results_do() {
    // docs/experiments.md: "... 27 of 40 done (26 on 2 CPU cores, 0.9-6.4 h each; ..." and
    // the scale table's "0.9-6.4 h each on 2 cores (3,296-22,896 s ..."; the status in
    // docs/results/experiments.md: "taken 0.9-6.4 hours (3,296-22,896 s, builds and tests".
    // The times are the CPU trainings' (a GPU's are stated apart, in minutes).
    let results = results(INTERFERENCE);
    let planned = planned_trainings(INTERFERENCE);
    let doc = flat(&read_doc("docs/experiments.md"));
    let on_cpu: Vec<&TrainResult> = results
        .iter()
        .filter(|r| !r.backend.as_deref().unwrap_or("cpu").starts_with("wgpu"))
        .collect();
    for (phrase, expected) in [
        (format!(" of {planned} done ("), results.len()),
        (" on 2 CPU cores, ".to_string(), on_cpu.len()),
    ] {
        for number in numbers_before(&doc, &phrase) {
            assert_eq!(number, expected, "docs/experiments.md: `{number}{phrase}`");
        }
    }
    let seconds = on_cpu.iter().map(|r| r.seconds);
    let shortest = seconds.clone().fold(f64::INFINITY, f64::min);
    let longest = seconds.fold(f64::NEG_INFINITY, f64::max);
    let in_seconds = (shortest.round(), longest.round());
    let in_hours = (
        (shortest / 360.0).round() / 10.0,
        (longest / 360.0).round() / 10.0,
    );
    let results_doc = flat_doc();
    for (doc, unit, expected) in [
        (&doc, " s on three machines", in_seconds),
        (&doc, " h each", in_hours),
        (&results_doc, " s, builds and tests", in_seconds),
        (&results_doc, " hours (", in_hours),
    ] {
        for range in ranges_before(doc, unit) {
            assert_eq!(range, expected, "the trainings took {expected:?}{unit}");
        }
    }
}
