//! The paper's findings beside ours: each claim with the paper's statistic, ours and its
//! effect as `docs/results/experiments.md` gives them (a test keeps the two the same), the
//! scale it was measured at, the committed figures, and a view of the shipped network that
//! shows it, with what to look at. The findings panel (`app::findings_panel`) draws them.

/// One claim of the paper and what the experiments found.
#[derive(Clone, Copy, Debug)]
pub struct Finding {
    /// The claim, in a sentence.
    pub claim: &'static str,
    /// The row of the findings tables in `docs/results/experiments.md` it comes from.
    pub row: &'static str,
    pub paper: &'static str,
    /// Our statistic and effect (with its interval), as the row gives them.
    pub ours: &'static str,
    pub effect: &'static str,
    /// The verdict the row's reading opens with (`docs/experiments.md` gives the rules).
    pub verdict: Verdict,
    /// Networks, iterations and trials behind `ours`.
    pub scale: &'static str,
    /// Figures, as paths under `docs/results/`.
    pub figures: &'static [&'static str],
    /// The view of the shipped network that shows it (a URL hash), if one can.
    pub view: Option<&'static str>,
    /// What to look at there.
    pub look: &'static str,
}

/// How a result stands to the paper's claim, by the rules of `docs/experiments.md`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Agrees,
    Disagrees,
    /// The tests point different ways (means against ranks, say): no verdict either way.
    Undecided,
    /// The paper describes figures; there is nothing to test.
    Descriptive,
    /// The networks behind it do not pass the validity gate (they lose to a baseline
    /// without dynamics on held-out data): no verdict either way.
    NotTestable,
}

impl Verdict {
    /// The words the results document's reading opens with.
    pub fn reading(self) -> &'static str {
        match self {
            Self::Agrees => "**Agrees**",
            Self::Disagrees => "**Disagrees**",
            Self::Undecided => "**Undecided**",
            Self::Descriptive => "No verdict (the paper describes figures)",
            Self::NotTestable => "**Not testable on these networks**",
        }
    }

    pub fn label(self) -> &'static str {
        match self {
            Self::Agrees => "agrees with the paper",
            Self::Disagrees => "disagrees with the paper",
            Self::Undecided => "undecided",
            Self::Descriptive => "no verdict: the paper describes figures",
            Self::NotTestable => "not testable on these networks (they fail the validity gate)",
        }
    }
}

pub const FINDINGS: &[Finding] = &[
    Finding {
        claim: "Each module contributes at its own time: the executive module while reaching, the others as the task proceeds",
        row: "When each module contributes (Figs 2B, 3A)",
        paper: "described in figures",
        ours: "executive, repositioning reaching / holding / lifting: 0.0093 ± 0.0020 / 0.0049 ± 0.0017 / 0.0055 ± 0.0009; wiping reaching / wiping / releasing: 0.0107 ± 0.0031 / 0.0091 ± 0.0024 / 0.0105 ± 0.0009; associative, repositioning 0.0237 / 0.0111 / 0.0176, wiping 0.0165 / 0.0100 / 0.0184",
        effect: "– (descriptive)",
        verdict: Verdict::Descriptive,
        scale: "converged campaign, networks 0-4 (5 networks, each trained 12,000-16,000 iterations to its validation best; 2 trials x 6 test sequences each)",
        figures: &[
            "converged/hierarchy/report/contributions_over_time_repositioning.png",
            "converged/hierarchy/report/contributions_over_time_wiping.png",
        ],
        view: Some("seq=repositioning_650mm_test0&t=40&maps=1"),
        look: "Turn to *Contributions over time*: one curve per module of how much zeroing its z changes the predicted image, and below the images the maps averaged over the cursor's subtask. Step through reaching (to 67), holding (to 178) and lifting. The four ablation runs compute live (minutes in a browser).",
    },
    Finding {
        claim: "The executive module's latent state changes most at subtask boundaries",
        row: "Executive change at subtask boundaries (Figs 2-3)",
        paper: "described, no test",
        ours: "near − elsewhere (t ≥ 30) −0.0003; across networks two-sided t(4), p = 0.79; within runs permutation p = 0.80",
        effect: "−0.0003 [−0.0030, +0.0024], d = −0.13; ±0.0036",
        verdict: Verdict::NotTestable,
        scale: "converged campaign, networks 0-4 (5 networks, each trained 12,000-16,000 iterations to its validation best; 2 trials x 6 test sequences each)",
        figures: &[],
        view: Some("seq=wiping_650mm_test0&t=83&d=0"),
        look: "Watch the executive module's mu traces (top) where the subtask bar under the time slider changes colour: steps 83 and 224 in this sequence.",
    },
    Finding {
        claim: "Where the arm hides the person, the reconstruction shows the hidden body",
        row: "Hidden body parts are inferred (Fig 3B), relative to the observed frame",
        paper: "pictures",
        ours: "reconstruction −0.0108, t(4) = −45.2, p < 0.001; from the 16x16 input −0.0107, p < 0.001; prior prediction −0.0108, p < 0.001",
        effect: "reconstruction −0.0108 [−0.0115, −0.0102], d = −20.2; ±0.0009",
        verdict: Verdict::NotTestable,
        scale: "converged campaign, networks 0-4 (5 networks, each trained 12,000-16,000 iterations to its validation best; 2 trials x 6 test sequences each)",
        figures: &["converged/hierarchy/report/contribution_maps.png"],
        view: Some("seq=repositioning_650mm_test0&t=120&contours=1"),
        look: "Compare the posterior reconstruction with the actual image where the arm passes over the person (the contours are the actual image's edges).",
    },
    Finding {
        claim: "Uncertainty (mean prior sigma) does not differ between the tasks",
        row: "Mean prior σ equal across tasks (Fig 4A), equivalence",
        paper: "t(4) = 1.67, p = 0.17",
        ours: "TOST vs ±0.125: 90% CI [+0.0048, +0.0127], p < 0.001: equivalent; paired t(4) = 4.70, p = 0.009",
        effect: "+0.0087 [+0.0036, +0.0139], d = 2.1; ±0.0069",
        verdict: Verdict::NotTestable,
        scale: "converged campaign, networks 0-4 (5 networks, each trained 12,000-16,000 iterations to its validation best; 2 trials x 6 test sequences each)",
        figures: &["converged/uncertainty/report/sigma_p.png"],
        view: Some("seq=wiping_650mm_test0&t=150"),
        look: "The bars under the traces are the run's Fig. 4: mean prior sigma per module. Switch the task to repositioning and compare.",
    },
    Finding {
        claim: "Uncertainty changes less over time in repositioning than in wiping",
        row: "σ changes less in repositioning (Fig 4B)",
        paper: "t(4) = −8.15, p = 0.0012",
        ours: "t(4) = −2.28, p = 0.085",
        effect: "−0.0013 [−0.0029, +0.0003], d = −1.0; ±0.0021",
        verdict: Verdict::NotTestable,
        scale: "converged campaign, networks 0-4 (5 networks, each trained 12,000-16,000 iterations to its validation best; 2 trials x 6 test sequences each)",
        figures: &["converged/uncertainty/report/sigma_p_change.png"],
        view: Some("seq=repositioning_650mm_test0&t=150"),
        look: "The right-hand bars: mean |change of prior sigma| per step; switch the task to wiping and compare.",
    },
    Finding {
        claim: "The full-resolution error rises as less of the vision is observed",
        row: "64x64 error rises as the observed resolution drops (Fig 5B)",
        paper: "F(2, 20) = 105.57, p < 0.001",
        ours: "ART F(2, 20) = 12.98, p < 0.001; 64 / 32+16 / 16: 0.00688 / 0.00674 / 0.00698",
        effect: "16 − 64 (proprio on): +0.00008 [−0.0007, +0.0009], d = 0.12; ±0.0011",
        verdict: Verdict::NotTestable,
        scale: "converged campaign, networks 0-4 (5 networks, each trained 12,000-16,000 iterations to its validation best; 2 trials x 6 test sequences each)",
        figures: &["converged/robustness/report/robustness.png"],
        view: Some("seq=repositioning_650mm_test0&t=120&compare=vision"),
        look: "The comparison window sets every observed resolution beside the others, with proprioception on and off; each cell's error is at the cursor and over the steps computed.",
    },
    Finding {
        claim: "Observing proprioception lowers the visual error, most at low resolution",
        row: "Proprioception lowers the error (Fig 5B)",
        paper: "F(1, 20) = 46.09, p < 0.001",
        ours: "ART F(1, 20) = 0.39, p = 0.54; on / off 0.00685 / 0.00689",
        effect: "off − on at 64: +0.00001 [−0.00017, +0.00019], d = 0.09; ±0.00024",
        verdict: Verdict::NotTestable,
        scale: "converged campaign, networks 0-4 (5 networks, each trained 12,000-16,000 iterations to its validation best; 2 trials x 6 test sequences each)",
        figures: &["converged/robustness/report/robustness.png"],
        view: Some("seq=repositioning_650mm_test0&t=120&compare=vision&vision=1&proprio=0"),
        look: "In the comparison window compare the proprioception on and off rows at 16x16; the main view shows 16x16 without proprioception.",
    },
    Finding {
        claim: "Learning wiping as well leaves repositioning's error unchanged",
        row: "Adding wiping data leaves repositioning unchanged (Fig 6A)",
        paper: "F(3, 16) = 0.62, p = 0.61",
        ours: "ART F(3, 16) = 28.51, p < 0.001 (pooled over all 32,284 sensory dimensions); TOST 9 added vs none: 90% CI [+2.30e-4, +3.26e-4] vs ±3.03e-4 (±10% of none's mean), p = 0.18: not equivalent",
        effect: "9 added − none, pooled: +2.78e-4 [+2.18e-4, +3.38e-4], d = 6.8; ±8.3e-5",
        verdict: Verdict::NotTestable,
        scale: "converged campaign, repositioning direction: 5 networks per condition x 4 conditions (20 trainings of 12,000-30,000 iterations to their validation best, one stopped at the cap; 2 trials x 3 test sequences each)",
        figures: &["converged/interference/report/interference_repositioning.png"],
        view: None,
        look: "Interference compares networks trained on different data: the shipped network cannot show it. The figure is the converged repositioning direction (5 networks per condition); the wiping direction is being trained and is tested once all its networks are.",
    },
    Finding {
        claim: "Learning more repositioning interferes with wiping, not the other way round",
        row: "Adding repositioning data raises wiping's error (Fig 6B), paper's pooled error",
        paper: "F(3, 16) = 19.16, p < 0.001",
        ours: "ART F(3, 8) = 1.07, p = 0.414 (pooled over all 32,284 sensory dimensions)",
        effect: "9 added − none: −1.1e-4 [−8.3e-4, +6.0e-4]; ±9.6e-4",
        verdict: Verdict::NotTestable,
        scale: "reduced scale: 3 x 5,000 per condition (networks x iterations)",
        figures: &["interference/report/interference_wiping.png"],
        view: None,
        look: "Interference compares networks trained on different data: the shipped network cannot show it. The figures are the reduced-scale runs (3 networks x 5,000 iterations per condition); the converged interference campaign is under way, and each direction is tested only once all its networks are trained.",
    },
];

/// The figures' bytes, built into the desktop app (the web site fetches them from
/// `findings/`, where Trunk copies `docs/results/`'s reports).
#[cfg(not(target_arch = "wasm32"))]
pub const FIGURES: &[(&str, &[u8])] = &[
    (
        "converged/hierarchy/report/contribution_maps.png",
        include_bytes!("../../../docs/results/converged/hierarchy/report/contribution_maps.png"),
    ),
    (
        "converged/hierarchy/report/contributions_over_time_repositioning.png",
        include_bytes!(
            "../../../docs/results/converged/hierarchy/report/contributions_over_time_repositioning.png"
        ),
    ),
    (
        "converged/hierarchy/report/contributions_over_time_wiping.png",
        include_bytes!(
            "../../../docs/results/converged/hierarchy/report/contributions_over_time_wiping.png"
        ),
    ),
    (
        "converged/robustness/report/robustness.png",
        include_bytes!("../../../docs/results/converged/robustness/report/robustness.png"),
    ),
    (
        "converged/uncertainty/report/sigma_p.png",
        include_bytes!("../../../docs/results/converged/uncertainty/report/sigma_p.png"),
    ),
    (
        "converged/uncertainty/report/sigma_p_change.png",
        include_bytes!("../../../docs/results/converged/uncertainty/report/sigma_p_change.png"),
    ),
    (
        "converged/interference/report/interference_repositioning.png",
        include_bytes!(
            "../../../docs/results/converged/interference/report/interference_repositioning.png"
        ),
    ),
    (
        "interference/report/interference_wiping.png",
        include_bytes!("../../../docs/results/interference/report/interference_wiping.png"),
    ),
];

/// Where the web site serves a figure: `findings/` + its path under `docs/results/`.
pub fn figure_url(path: &str) -> String {
    format!("findings/{path}")
}
