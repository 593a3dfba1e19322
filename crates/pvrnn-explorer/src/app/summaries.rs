//! Summaries: the paper's Fig. 4 uncertainty numbers of the shown run.

use super::palette::unit_colour;
use super::*;

/// Fig. 4 for the shown run: per module, the mean prior sigma and its mean absolute change
/// between steps.
pub(super) fn uncertainty_ui(ui: &mut egui::Ui, trace: &RunTrace) {
    let summary = uncertainty(trace);
    ui.label(
        RichText::new("uncertainty (Fig. 4): mean prior sigma and its mean |change| per step")
            .small(),
    );
    ui.columns(2, |cols| {
        for (col, (title, pick)) in cols.iter_mut().zip([
            ("mean prior sigma", 0usize),
            ("mean |change of prior sigma|", 1usize),
        ]) {
            let bars: Vec<Bar> = summary
                .iter()
                .enumerate()
                .map(|(i, (name, v))| {
                    Bar::new(i as f64, [v.0, v.1][pick])
                        .name(name.to_string())
                        .fill(unit_colour(i))
                })
                .collect();
            col.label(RichText::new(title).small());
            Plot::new(format!("uncertainty {pick}"))
                .height(100.0)
                .allow_drag(false)
                .allow_zoom(false)
                .allow_scroll(false)
                .show_x(false)
                .show(col, |pu| {
                    pu.bar_chart(BarChart::new(title, bars).width(0.7));
                });
            let text = summary
                .iter()
                .map(|(n, v)| format!("{n} {:.4}", [v.0, v.1][pick]))
                .collect::<Vec<_>>()
                .join("   ");
            col.label(RichText::new(text).small().monospace());
        }
    });
}

/// Per module (and all together): (mean prior sigma, mean |prior sigma(t) - prior sigma(t-1)|).
pub fn uncertainty(trace: &RunTrace) -> Vec<(&'static str, (f64, f64))> {
    let mut out = Vec::new();
    let (mut all_mean, mut all_change, mut all_n, mut all_m) = (0.0, 0.0, 0usize, 0usize);
    for (m, name) in ["Exe", "Mul", "Ext", "Pro"].into_iter().enumerate() {
        let z = trace.z[m];
        let s = &trace.modules[m].sigma_p;
        let steps = trace.steps;
        let mean: f64 = s[..steps * z].iter().map(|&v| v as f64).sum::<f64>();
        let change: f64 = (1..steps)
            .flat_map(|t| (0..z).map(move |u| (t, u)))
            .map(|(t, u)| (s[t * z + u] - s[(t - 1) * z + u]).abs() as f64)
            .sum();
        let n = steps * z;
        let c = steps.saturating_sub(1) * z;
        out.push((name, (mean / n.max(1) as f64, change / c.max(1) as f64)));
        all_mean += mean;
        all_change += change;
        all_n += n;
        all_m += c;
    }
    out.push((
        "All",
        (
            all_mean / all_n.max(1) as f64,
            all_change / all_m.max(1) as f64,
        ),
    ));
    out
}
