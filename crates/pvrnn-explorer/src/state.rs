//! The view state (sequence, time, conditions, selected units, what is shown), and its
//! text form in the URL hash so a view can be shared and reopened, e.g.
//! `#seq=wiping_650mm_test0&t=120&vision=1&proprio=1&ablate=1000&H=30&iter=50&lr=0.09&seed=0&units=0-14`.

use crate::bundle::Bundle;
use crate::condition::Condition;
use crate::driving::EPISODE_SO_FAR;

/// Which conditions the comparison view sets side by side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CompareSet {
    /// Vision observed (every lowest-levels choice) x proprioception on / off: the paper's
    /// Fig. 5 question.
    Vision,
    /// No ablation and each module ablated alone.
    Ablation,
}

impl CompareSet {
    pub fn name(self) -> &'static str {
        match self {
            Self::Vision => "vision",
            Self::Ablation => "ablation",
        }
    }
    pub fn parse(text: &str) -> Option<Self> {
        [Self::Vision, Self::Ablation]
            .into_iter()
            .find(|c| c.name() == text)
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct ViewState {
    pub sequence: Option<String>,
    pub t: usize,
    /// `None`: the model's standard condition.
    pub condition: Option<Condition>,
    /// Latent units shown in the plots.
    pub units: Vec<usize>,
    /// Show d traces.
    pub show_d: bool,
    /// Predicted images: the one-step prior prediction instead of the posterior reconstruction.
    pub prior_images: bool,
    /// Draw the actual image's contours over the pictures.
    pub contours: bool,
    /// Compute and show the ablation contribution maps.
    pub maps: bool,
    pub playing: bool,
    /// Playback speed in steps per second.
    pub speed: f32,
    /// The comparison view, when open.
    pub compare: Option<CompareSet>,
    /// A branch of the shown run, shown beside it.
    pub branch: Option<BranchView>,
    /// The latent traces and summaries show the branch instead of its run.
    pub branch_traces: bool,
    /// Trials (noise seeds from the condition's on) the contributions over time average.
    pub map_trials: u8,
    /// A second network to open beside the first: a bundle's address relative to the site
    /// (in the browser) or to the working folder (on the desktop), e.g. `models/early/`.
    pub second: Option<String>,
    /// The drive whose episode is shown (`pvrnn_drive::DriveSpec::to_text`): the app runs
    /// it when its episode is not open yet, so a link replays it.
    pub drive: Option<String>,
}

/// Reads an address entry that names something to open: a drive (`drive=`) or a second
/// network (`second=`, a relative address only); `off` removes it. Whether it was read.
fn read_link(v: &mut ViewState, key: &str, value: &str) -> bool {
    let slot = if key == "drive" {
        &mut v.drive
    } else {
        &mut v.second
    };
    if value == "off" {
        *slot = None;
        return true;
    }
    let read = decode(value).filter(|a| key == "drive" || relative_address(a));
    read.map(|a| *slot = Some(a)).is_some()
}

/// The sequence name of a drive's episode under a condition: everything the episode
/// depends on, so one name is one episode.
pub fn drive_episode_name(spec_text: &str, c: &Condition) -> String {
    let ablated: String = c
        .ablation
        .iter()
        .map(|&a| if a { '1' } else { '0' })
        .collect();
    format!(
        "drive {spec_text} | vision {} proprio {} ablate {ablated} {:?} H {} it {} lr {} seed {}",
        c.vision_levels,
        c.proprio as u8,
        c.ablation_mode,
        c.window,
        c.iterations,
        c.lr(),
        c.seed
    )
}

/// A branch of the shown run: the same run up to step `at`, then under `condition`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BranchView {
    pub at: usize,
    pub condition: Condition,
}

impl Default for ViewState {
    fn default() -> Self {
        Self {
            sequence: None,
            t: 0,
            condition: None,
            units: (0..15).collect(),
            show_d: false,
            prior_images: false,
            contours: false,
            // Off by default: four extra runs per condition (minutes at full vision in a browser).
            maps: false,
            playing: false,
            speed: 10.0,
            compare: None,
            branch: None,
            branch_traces: false,
            map_trials: 1,
            second: None,
            drive: None,
        }
    }
}

fn encode(s: &str) -> String {
    let mut out = String::new();
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || b"-_.".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

fn decode(s: &str) -> Option<String> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = s.get(i + 1..i + 3)?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// `0-3,7` from a sorted list of units.
pub fn format_units(units: &[usize]) -> String {
    let mut parts = Vec::new();
    let mut i = 0;
    while i < units.len() {
        let start = units[i];
        let mut end = start;
        while i + 1 < units.len() && units[i + 1] == end + 1 {
            i += 1;
            end = units[i];
        }
        parts.push(if end > start {
            format!("{start}-{end}")
        } else {
            start.to_string()
        });
        i += 1;
    }
    parts.join(",")
}

/// Parses `0-3,7` (sorted, deduplicated); `None` if malformed.
pub fn parse_units(text: &str) -> Option<Vec<usize>> {
    let mut units = Vec::new();
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b): (usize, usize) = (a.trim().parse().ok()?, b.trim().parse().ok()?);
                if b < a || b - a > 10_000 {
                    return None;
                }
                units.extend(a..=b);
            }
            None => units.push(part.parse().ok()?),
        }
    }
    units.sort_unstable();
    units.dedup();
    Some(units)
}

impl ViewState {
    /// Makes the view one the bundle can show, whatever it came from (a URL hash, `--view`,
    /// a new bundle, the controls): an unknown sequence becomes the first one, time and the
    /// observed vision levels are clamped. Returns what was changed, for the status line.
    pub fn sanitize(&mut self, bundle: &Bundle) -> Vec<String> {
        let mut notes = Vec::new();
        let known = self
            .sequence
            .as_ref()
            .is_some_and(|s| bundle.dataset.by_name(s).is_some());
        if !known {
            let first = bundle
                .dataset
                .sequences
                .first()
                .map(|s| s.info.name.clone());
            let standard = Condition::standard(&bundle.model.config);
            let pending = self
                .drive
                .as_ref()
                .map(|d| drive_episode_name(d, &self.condition.unwrap_or(standard)));
            if let Some(unknown) = self
                .sequence
                .as_ref()
                .filter(|s| Some(*s) != pending.as_ref())
            {
                notes.push(format!(
                    "no sequence `{}` in this model's data: showing `{}`",
                    quoted(unknown),
                    first.as_deref().unwrap_or("none")
                ));
                self.t = 0;
            }
            self.sequence = first;
        }
        let len = self
            .sequence
            .as_ref()
            .and_then(|s| bundle.dataset.by_name(s))
            .map_or(1, |s| s.len());
        if self.t >= len {
            notes.push(format!(
                "time {} is past the sequence's end: showing its last step, {}",
                self.t,
                len - 1
            ));
            self.t = len - 1;
        }
        let levels = bundle.model.config.vision.resolutions.len();
        let branch = self.branch.as_mut().map(|b| &mut b.condition);
        for c in self.condition.as_mut().into_iter().chain(branch) {
            if c.vision_levels as usize > levels {
                notes.push(format!(
                    "vision levels {} asked for, the model has {levels}: observing all",
                    c.vision_levels
                ));
                c.vision_levels = levels as u8;
            }
        }
        if let Some(b) = self.branch.filter(|b| b.at >= len) {
            notes.push(format!(
                "a branch at step {}, past the sequence's last step ({}): no branch",
                b.at,
                len - 1
            ));
            self.branch = None;
        }
        notes
    }

    /// The hash text (without `#`).
    pub fn to_hash(&self) -> String {
        let mut parts = Vec::new();
        // The episode being driven is not a sequence a link can open (the drive is).
        let driving = self.sequence.as_deref() == Some(EPISODE_SO_FAR);
        if let Some(s) = &self.sequence
            && !driving
        {
            parts.push(format!("seq={}", encode(s)));
        }
        parts.push(format!("t={}", self.t));
        if let Some(c) = &self.condition {
            condition_entries(c, "", &mut parts);
        }
        if let Some(b) = &self.branch {
            parts.push(format!("branch={}", b.at));
            condition_entries(&b.condition, BRANCH, &mut parts);
        }
        parts.push(format!("units={}", format_units(&self.units)));
        if self.map_trials > 1 {
            parts.push(format!("trials={}", self.map_trials));
        }
        if let Some(c) = self.compare {
            parts.push(format!("compare={}", c.name()));
        }
        if let Some(second) = &self.second {
            parts.push(format!("second={}", encode(second)));
        }
        // Only while its episode is shown (or driven): a link to another sequence does not
        // drive.
        if let (Some(drive), Some(c)) = (&self.drive, &self.condition)
            && (driving || self.sequence.as_deref() == Some(drive_episode_name(drive, c).as_str()))
        {
            parts.push(format!("drive={}", encode(drive)));
        }
        for (key, on) in [
            ("d", self.show_d),
            ("prior", self.prior_images),
            ("contours", self.contours),
            ("maps", self.maps),
            ("btraces", self.branch_traces),
        ] {
            parts.push(format!("{key}={}", on as u8));
        }
        parts.join("&")
    }

    /// Reads a hash (with or without `#`); missing or malformed keys keep `base`'s values,
    /// and each entry ignored that way is named in the returned notes (shown to the user).
    /// Condition keys need the `standard` condition to fill what the hash leaves out.
    pub fn from_hash(
        hash: &str,
        base: &ViewState,
        standard: Condition,
    ) -> (ViewState, Vec<String>) {
        let mut v = base.clone();
        let mut c = base.condition.unwrap_or(standard);
        let mut condition_given = false;
        // A branch's condition starts from the view's own (a hash that names only what
        // the branch changes).
        let mut branch = base.branch.unwrap_or(BranchView {
            at: 0,
            condition: c,
        });
        let mut branch_given = base.branch.is_some();
        let mut ignored = Vec::new();
        for pair in hash.trim_start_matches('#').split('&') {
            if pair.is_empty() {
                continue;
            }
            let Some((key, value)) = pair.split_once('=') else {
                ignored.push(pair.to_string());
                continue;
            };
            let num = || value.parse::<u64>().ok();
            let flag = || match value {
                "1" | "true" => Some(true),
                "0" | "false" => Some(false),
                _ => None,
            };
            // Whether the entry was read; a condition entry that was also sets the condition.
            let (read, sets_condition) = match key {
                "seq" => (
                    decode(value).map(|name| v.sequence = Some(name)).is_some(),
                    false,
                ),
                "t" => (num().map(|n| v.t = n as usize).is_some(), false),
                "units" => (parse_units(value).map(|u| v.units = u).is_some(), false),
                "d" => (flag().map(|f| v.show_d = f).is_some(), false),
                "prior" => (flag().map(|f| v.prior_images = f).is_some(), false),
                "contours" => (flag().map(|f| v.contours = f).is_some(), false),
                "maps" => (flag().map(|f| v.maps = f).is_some(), false),
                "btraces" => (flag().map(|f| v.branch_traces = f).is_some(), false),
                "trials" => (
                    num()
                        .filter(|&n| (1..=10).contains(&n))
                        .map(|n| v.map_trials = n as u8)
                        .is_some(),
                    false,
                ),
                "compare" => {
                    let set = match value {
                        "off" | "0" => Some(None),
                        other => CompareSet::parse(other).map(Some),
                    };
                    (set.map(|set| v.compare = set).is_some(), false)
                }
                "drive" | "second" => (read_link(&mut v, key, value), false),
                "branch" if value == "off" => {
                    branch_given = false;
                    (true, false)
                }
                "branch" => {
                    let at = num().map(|n| n as usize);
                    if let Some(at) = at {
                        branch.at = at;
                        branch_given = true;
                    }
                    (at.is_some(), false)
                }
                _ => match key.strip_prefix(BRANCH) {
                    Some(key) => match read_condition_entry(&mut branch.condition, key, value) {
                        Some(read) => (read, false),
                        None => (false, false),
                    },
                    None => match read_condition_entry(&mut c, key, value) {
                        Some(read) => (read, true),
                        None => (false, false),
                    },
                },
            };
            if read {
                condition_given |= sets_condition;
            } else {
                ignored.push(pair.to_string());
            }
        }
        if condition_given {
            v.condition = Some(c);
        }
        v.branch = branch_given.then_some(branch);
        let notes = if ignored.is_empty() {
            Vec::new()
        } else {
            let shown: Vec<String> = ignored.iter().take(6).map(|e| quoted(e)).collect();
            let more = ignored.len().saturating_sub(shown.len());
            vec![format!(
                "ignored in the view's address: `{}`{} (unknown key or value out of range)",
                shown.join("`, `"),
                if more > 0 {
                    format!(" and {more} more")
                } else {
                    String::new()
                }
            )]
        };
        (v, notes)
    }
}

/// Whether `address` names a place relative to the site (or the working folder): not
/// absolute, no scheme (`https:`, `data:`, `javascript:`), no drive, and of a sane length.
/// A link may open a second network from the site it was made on, not from anywhere.
pub fn relative_address(address: &str) -> bool {
    let first = address.split('/').next().unwrap_or("");
    !address.is_empty()
        && address.len() <= 300
        && !address.starts_with(['/', '\\'])
        && !first.contains(':')
        && !address.chars().any(char::is_control)
}

/// A value from the address as a message quotes it: at most 48 characters, control
/// characters shown as `?`, so that a long or hostile address cannot fill or garble the
/// status line.
pub fn quoted(value: &str) -> String {
    const MAX: usize = 48;
    let clean = |c: char| if c.is_control() { '?' } else { c };
    let count = value.chars().count();
    if count <= MAX {
        value.chars().map(clean).collect()
    } else {
        let head: String = value.chars().take(MAX).map(clean).collect();
        format!("{head}… ({count} characters)")
    }
}

/// The prefix of a branch's condition entries in the hash (`b.vision=0`).
const BRANCH: &str = "b.";

/// A condition's entries in the hash, each key after `prefix`.
fn condition_entries(c: &Condition, prefix: &str, parts: &mut Vec<String>) {
    let ablate: String = c
        .ablation
        .iter()
        .map(|&a| if a { '1' } else { '0' })
        .collect();
    for (key, value) in [
        ("vision", c.vision_levels.to_string()),
        ("proprio", (c.proprio as u8).to_string()),
        ("ablate", ablate),
        ("amode", c.ablation_mode.name().to_string()),
        ("H", c.window.to_string()),
        ("iter", c.iterations.to_string()),
        ("lr", c.lr().to_string()),
        ("seed", c.seed.to_string()),
    ] {
        parts.push(format!("{prefix}{key}={value}"));
    }
}

/// Reads one condition entry into `c`: `None` when `key` is not a condition's, else
/// whether the value was read (a malformed one leaves `c` as it was).
fn read_condition_entry(c: &mut Condition, key: &str, value: &str) -> Option<bool> {
    let num = || value.parse::<u64>().ok();
    let flag = || match value {
        "1" | "true" => Some(true),
        "0" | "false" => Some(false),
        _ => None,
    };
    Some(match key {
        "vision" => num()
            .filter(|&n| n <= 8)
            .map(|n| c.vision_levels = n as u8)
            .is_some(),
        "proprio" => flag().map(|f| c.proprio = f).is_some(),
        "ablate" => {
            let ok = value.len() == 4 && value.chars().all(|ch| ch == '0' || ch == '1');
            if ok {
                for (slot, ch) in c.ablation.iter_mut().zip(value.chars()) {
                    *slot = ch == '1';
                }
            }
            ok
        }
        "amode" => pvrnn_core::AblationMode::parse(value)
            .map(|mode| c.ablation_mode = mode)
            .is_ok(),
        "H" => num()
            .filter(|&n| (1..=10_000).contains(&n))
            .map(|n| c.window = n as u16)
            .is_some(),
        "iter" => num()
            .filter(|&n| n <= 10_000)
            .map(|n| c.iterations = n as u16)
            .is_some(),
        "lr" => value
            .parse::<f64>()
            .ok()
            .filter(|lr| *lr > 0.0 && *lr <= 100.0)
            .map(|lr| c.set_lr(lr))
            .is_some(),
        "seed" => num()
            .filter(|&n| n <= u32::MAX as u64)
            .map(|n| c.seed = n as u32)
            .is_some(),
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn standard() -> Condition {
        Condition::standard(&pvrnn_core::ModelConfig::default())
    }

    #[test]
    fn a_second_network_is_named_only_relative_to_the_site() {
        for ok in ["models/early/", "../runs/late", "early", "models/a b/"] {
            assert!(relative_address(ok), "{ok}");
        }
        for hostile in [
            "",
            "/etc/models",
            "//evil.example/m/",
            "https://evil.example/m/",
            "javascript:alert(1)",
            "data:text/plain,x",
            "C:\\models",
            "\\\\server\\share",
            "models/\nnewline",
        ] {
            assert!(!relative_address(hostile), "{hostile:?}");
        }
        let base = ViewState::default();
        let (v, notes) =
            ViewState::from_hash("second=https%3A%2F%2Fevil.example%2F", &base, standard());
        assert_eq!(v.second, None);
        assert!(notes[0].contains("second=https"), "{notes:?}");
        let (v, notes) = ViewState::from_hash("second=models%2Fearly%2F", &base, standard());
        assert_eq!(
            (v.second.as_deref(), notes.len()),
            (Some("models/early/"), 0)
        );
        let (v, _) = ViewState::from_hash("second=off", &v, standard());
        assert_eq!(v.second, None);
    }

    #[test]
    fn hash_round_trip() {
        let mut c = standard();
        c.vision_levels = 1;
        c.proprio = false;
        c.ablation = [true, false, false, true];
        c.ablation_mode = pvrnn_core::AblationMode::Inference;
        c.iterations = 20;
        c.seed = 7;
        // A rate that no fixed number of decimals holds survives exactly.
        c.set_lr(0.0905 / 3.0);
        let v = ViewState {
            sequence: Some("wiping 650/test#0".into()),
            t: 123,
            condition: Some(c),
            units: vec![0, 1, 2, 5, 9, 10],
            show_d: true,
            prior_images: true,
            contours: true,
            maps: false,
            branch_traces: true,
            map_trials: 3,
            compare: Some(CompareSet::Vision),
            second: Some("models/early checkpoint/".into()),
            branch: Some(BranchView {
                at: 80,
                condition: Condition {
                    vision_levels: 0,
                    proprio: true,
                    ..c
                },
            }),
            ..ViewState::default()
        };
        let hash = v.to_hash();
        assert!(
            hash.contains("units=0-2,5,9-10")
                && hash.contains("ablate=1001")
                && hash.contains("amode=inference")
                && hash.contains("branch=80&b.vision=0&b.proprio=1"),
            "{hash}"
        );
        let (back, notes) =
            ViewState::from_hash(&format!("#{hash}"), &ViewState::default(), standard());
        assert!(notes.is_empty(), "{notes:?}");
        assert_eq!(
            back,
            ViewState {
                playing: false,
                speed: v.speed,
                ..v
            }
        );
    }

    #[test]
    fn malformed_values_keep_the_current_ones() {
        let base = ViewState::default();
        let (v, notes) =
            ViewState::from_hash("t=abc&units=3-1&vision=x&junk&ablate=12", &base, standard());
        assert_eq!(v, base);
        // Each ignored entry is named for the user.
        assert_eq!(notes.len(), 1);
        for entry in ["t=abc", "units=3-1", "vision=x", "junk", "ablate=12"] {
            assert!(notes[0].contains(&format!("`{entry}`")), "{notes:?}");
        }
        assert_eq!(parse_units("4, 2-3"), Some(vec![2, 3, 4]));
        assert_eq!(parse_units("a"), None);
    }

    #[test]
    fn long_or_hostile_address_values_are_shortened_in_messages() {
        let long = format!("t={}", "9".repeat(400));
        let odd = "x=\u{1b}[2Jboo";
        let many: String = (0..20).map(|i| format!("&k{i}=v")).collect();
        let (_, notes) = ViewState::from_hash(
            &format!("{long}&{odd}{many}"),
            &ViewState::default(),
            standard(),
        );
        let note = &notes[0];
        assert!(note.chars().count() < 400, "{note}");
        assert!(note.contains("… (402 characters)"), "{note}");
        assert!(
            note.contains("x=?[2Jboo") && !note.contains('\u{1b}'),
            "{note}"
        );
        assert!(note.contains(" and 16 more"), "{note}");
        assert_eq!(quoted("seq=ok"), "seq=ok");
    }
}
