//! PNG pictures: each sequence's error over time with its subtask bar, actual vs predicted
//! images, and training curves; bar charts also as SVG. Text uses an embedded font, so
//! pictures look the same on every machine.
//!
//! One family of figures per file:
//! - `canvas.rs`: what every figure shares: the embedded font, the colours, PNG and SVG
//!   canvases, axis ticks, and [`write_png`] for a ready picture.
//! - `lines.rs`: a chart of lines on a log-scaled y axis.
//! - `sequences.rs`: each evaluated sequence's errors over time with its subtask bar
//!   ([`write_plots`]).
//! - `images.rs`: each evaluated sequence's actual vs predicted images.
//! - `training.rs`: training and validation curves ([`training_curves`],
//!   [`validation_curves`]).
//! - `bars.rs`: grouped bar charts with ±SE whiskers, as PNG and SVG ([`bar_chart`]).
//! - `maps.rs`: a labelled grid of grey maps ([`labelled_maps`]).

mod bars;
mod canvas;
mod images;
mod lines;
mod maps;
mod sequences;
mod training;

pub use bars::{Bar, bar_chart};
pub use canvas::write_png;
pub use maps::labelled_maps;
pub use sequences::write_plots;
pub use training::{training_curves, validation_curves};
