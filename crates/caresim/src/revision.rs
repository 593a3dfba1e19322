//! Which edition of the benchmark to simulate.
//!
//! Revision 1 (November 2026) scripted the hands' positions and finger directions only: the
//! wrist's last joint never turned (0.0014 rad in all over seed 0), and every load acted
//! on the joint axis through the palm's centre and straight down, so the torques of both
//! wrist rolls and of the left shoulder's vertical joint were sensor noise alone. Min-max
//! normalisation stretched those 5 of 28 channels to the full range: noise of std 0.25 in
//! model units against 0.01-0.09 on the others. Revision 2 moves and loads them as a
//! teleoperated arm would (docs/caresim.md, "Revisions"):
//! - the operator twists the wrist: the palm turns up to slide under the neck, the knee
//!   hand turns the other way, the towel hand turns to pinch the towel and rolls with each
//!   stroke;
//! - loads act where the palm touches, 4 cm from the wrist's axis, so they turn the wrist;
//! - the back presses along its own normal, which tilts as the upper body is lifted, and
//!   resists the hand sliding under it with friction.
//!
//! A dataset records its revision in its source text; the random draws of a trial are the
//! same in both, so a trial of revision 2 is the revision-1 trial with its wrists turned
//! and its loads placed.

use std::fmt;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Revision {
    /// The benchmark the shipped model and the experiments of November 2026 learned.
    #[default]
    R1,
    /// Every joint moved and every torque loaded.
    R2,
}

impl Revision {
    pub const ALL: [Revision; 2] = [Revision::R1, Revision::R2];

    pub fn number(self) -> u32 {
        match self {
            Revision::R1 => 1,
            Revision::R2 => 2,
        }
    }

    /// `1` or `2`.
    pub fn parse(text: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|r| text.trim() == r.number().to_string())
            .ok_or_else(|| format!("`{text}` is not a caresim revision (1 or 2)"))
    }
}

impl fmt::Display for Revision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.number())
    }
}
