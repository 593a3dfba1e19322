//! The findings panel cannot drift from the results: every statistic it shows is in
//! `docs/results/experiments.md`'s row for its claim, every figure is a committed one that
//! the web site copies, and every link lands on a view of the shipped network that shows
//! what the finding says to look at.

use crate::common;

use std::path::Path;

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use pvrnn_explorer::findings::{FIGURES, FINDINGS};
use pvrnn_explorer::state::CompareSet;
use pvrnn_explorer::{Bundle, Condition, ExplorerApp, ViewState};

fn repo() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
}

#[test]
fn every_statistic_is_the_results_document_s() {
    let doc = std::fs::read_to_string(repo().join("docs/results/experiments.md")).unwrap();
    for f in FINDINGS {
        let rows: Vec<&str> = doc
            .lines()
            .filter(|l| l.starts_with(&format!("| {} |", f.row)))
            .collect();
        assert!(!rows.is_empty(), "no row `{}` in experiments.md", f.row);
        assert!(
            rows.iter()
                .any(|r| r.contains(f.ours) && r.contains(f.effect)),
            "`{}`: its statistic or effect is not experiments.md's",
            f.row
        );
        // The verdict is the reading's: the row's last cell opens with it.
        assert!(
            rows.iter().any(|r| r.contains(f.ours)
                && r.trim_end_matches(" |")
                    .rsplit(" | ")
                    .next()
                    .is_some_and(|reading| reading.starts_with(f.verdict.reading()))),
            "`{}`: the verdict is not experiments.md's reading",
            f.row
        );
        assert!(f.scale.contains("networks"), "`{}` names no scale", f.row);
    }
}

#[test]
fn every_figure_is_committed_built_in_and_served() {
    let page = std::fs::read_to_string(repo().join("web/index.html")).unwrap();
    for f in FINDINGS {
        for &path in f.figures {
            let file = repo().join("docs/results").join(path);
            let built_in = FIGURES.iter().find(|(p, _)| *p == path).unwrap().1;
            assert_eq!(std::fs::read(&file).unwrap(), built_in, "{path}");
            let dir = Path::new(path).parent().unwrap().to_str().unwrap();
            assert!(
                page.contains(&format!(
                    "href=\"../docs/results/{dir}\" data-target-path=\"findings/{dir}\""
                )),
                "web/index.html does not copy {dir}"
            );
        }
    }
}

#[test]
fn every_link_lands_on_a_view_of_the_shipped_network() {
    let bundle = Bundle::open_dir(&repo().join("models/default")).unwrap();
    let standard = Condition::standard(&bundle.model.config);
    for f in FINDINGS {
        let Some(hash) = f.view else { continue };
        let (mut view, notes) = ViewState::from_hash(hash, &ViewState::default(), standard);
        assert!(notes.is_empty(), "{hash}: {notes:?}");
        assert_eq!(view.sanitize(&bundle), Vec::<String>::new(), "{hash}");
        // The panel the sentence sends the reader to is open.
        let look = f.look;
        assert_eq!(
            look.contains("Contributions over time"),
            view.maps,
            "{hash}"
        );
        assert_eq!(
            look.contains("comparison window"),
            view.compare == Some(CompareSet::Vision),
            "{hash}"
        );
        assert_eq!(look.contains("contours"), view.contours, "{hash}");
        let seq = bundle
            .dataset
            .by_name(view.sequence.as_deref().unwrap())
            .unwrap();
        // A step the sentence names is in the sequence, and a subtask it names starts there.
        for word in look
            .split(|c: char| !c.is_ascii_digit())
            .filter(|w| !w.is_empty())
        {
            let step: usize = word.parse().unwrap();
            if step > 16 && step < 1000 {
                assert!(step < seq.len(), "{hash}: step {step}");
            }
        }
        if hash.contains("t=83") {
            assert_ne!(seq.subtask[82], seq.subtask[83], "no boundary at 83");
        }
    }
}

#[test]
fn the_panel_lists_every_claim_and_its_link_opens_the_view() {
    let mut h = Harness::builder()
        .with_size(eframe::egui::vec2(1400.0, 1000.0))
        .build_ui_state(
            |ui, app: &mut ExplorerApp| app.show(ui),
            ExplorerApp::new(Some(common::bundle()), ViewState::default()),
        );
    h.run_steps(3);
    h.get_by_label("Findings").click();
    h.run_steps(3);
    let labels = format!("{:?}", h.root());
    for f in FINDINGS {
        assert!(labels.contains(f.claim), "no `{}`", f.claim);
    }
    // The first finding is open: its statistics, its figures read, its link.
    for text in [
        FINDINGS[0].paper,
        FINDINGS[0].ours,
        FINDINGS[0].scale,
        FINDINGS[0].verdict.label(),
    ] {
        assert!(labels.contains(text), "no `{text}`");
    }
    assert!(!labels.contains("figure not available"), "{labels}");
    // A figure opens full size in a window of its own, at its own pixel size.
    let first = FINDINGS[0].figures[0];
    h.get_by_label(&format!("figure {first}")).click();
    h.run_steps(3);
    let labels = format!("{:?}", h.root());
    assert!(
        labels.contains(&format!("docs/results/{first}")),
        "{labels}"
    );
    h.get_by_label("Show it on the shipped network").click();
    h.run_steps(2);
    let view = h.state().view();
    assert!(
        view.maps,
        "the first finding's view shows the contributions"
    );
    // The test bundle lacks the shipped network's sequence, and says so.
    let status = format!("{:?}", h.state().status());
    assert!(status.contains("repositioning_650mm_test0"), "{status}");
}
