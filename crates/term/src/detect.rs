//! Which image protocol to draw with, and a cell's size in pixels, for `preview`
//! and `inspect` alike: `--protocol` first; inside tmux, what the tmux server says
//! of the outer terminal; else the terminal's own answers to the probe (its name
//! from XTVERSION, then the kitty query, then DA1's sixel attribute); then
//! environment hints; then text (symbols in colour, [`crate::symbols`]), with a
//! note saying why.
//!
//! [`choose`] is a pure function of what was learnt (tested for every terminal we
//! know); [`detect`] does the asking.

use super::Protocol;
use super::probe::{self, Probe, WinSize};
use super::replies::Replies;
use super::tmux::{self, TmuxInfo};
use crate::symbols::{SymbolSet, TextStyle, choose_text};
use serde::Serialize;
use std::io::IsTerminal;
use std::os::fd::AsRawFd;
use std::time::{Duration, Instant};

/// The image protocol a frame is drawn with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Graphics {
    Kitty,
    Sixel,
    Iterm2,
    Halfblocks,
}

impl Graphics {
    pub fn name(&self) -> &'static str {
        match self {
            Graphics::Kitty => "kitty",
            Graphics::Sixel => "sixel",
            Graphics::Iterm2 => "iTerm2",
            Graphics::Halfblocks => "text",
        }
    }
}

/// The environment variables the choice looks at.
#[derive(Debug, Clone, Default, Serialize)]
pub struct TerminalEnv {
    pub term: Option<String>,
    pub term_program: Option<String>,
    pub kitty_window_id: Option<String>,
    pub tmux: Option<String>,
    pub tmux_pane: Option<String>,
    pub lc_terminal: Option<String>,
    /// `truecolor` or `24bit` where the terminal takes 24-bit colour.
    pub colorterm: Option<String>,
}

impl TerminalEnv {
    /// This process's environment.
    pub(crate) fn from_process() -> TerminalEnv {
        let var = |k: &str| std::env::var(k).ok().filter(|v| !v.is_empty());
        TerminalEnv {
            term: var("TERM"),
            term_program: var("TERM_PROGRAM"),
            kitty_window_id: var("KITTY_WINDOW_ID"),
            tmux: var("TMUX"),
            tmux_pane: var("TMUX_PANE"),
            lc_terminal: var("LC_TERMINAL"),
            colorterm: var("COLORTERM"),
        }
    }

    /// Whether we run inside tmux.
    pub fn in_tmux(&self) -> bool {
        self.tmux.is_some()
    }

    /// The protocol the variables suggest (after SSH most are gone).
    pub fn hint(&self) -> Option<(Graphics, String)> {
        let term = self.term.as_deref().unwrap_or("").to_ascii_lowercase();
        let program = self.term_program.as_deref().unwrap_or("");
        if self.kitty_window_id.is_some() {
            return Some((Graphics::Kitty, "KITTY_WINDOW_ID is set".into()));
        }
        if let Some(g) = by_name(program).or_else(|| by_name(&term)) {
            return Some((g, format!("TERM={term}, TERM_PROGRAM={program}")));
        }
        if self.lc_terminal.as_deref() == Some("iTerm2") {
            return Some((Graphics::Iterm2, "LC_TERMINAL=iTerm2".into()));
        }
        if term.contains("sixel") || term.contains("mlterm") {
            return Some((Graphics::Sixel, format!("TERM={term}")));
        }
        None
    }
}

/// The protocol a terminal draws best, by its name (XTVERSION's text, `TERM` or
/// `TERM_PROGRAM`). Named first because several terminals answer the kitty query
/// `OK` but lack what we use (Unicode placeholders: WezTerm, Konsole).
pub(crate) fn by_name(name: &str) -> Option<Graphics> {
    let n = name.to_ascii_lowercase();
    let has = |s: &str| n.contains(s);
    if has("kitty") || has("ghostty") || n.starts_with("rio") {
        Some(Graphics::Kitty)
    } else if has("wezterm") || has("iterm") || has("mintty") {
        Some(Graphics::Iterm2)
    } else if has("konsole") || has("foot") || has("mlterm") || has("contour") {
        Some(Graphics::Sixel)
    } else {
        None
    }
}

/// The first kitty that draws Unicode placeholders (`U=1`): older ones reject the
/// key as a malformed command (`invalid key character: 0x55`), draw nothing, and
/// show the placeholder cells as glyphs. Every kitty since 0.21.2 says its version
/// to XTVERSION (`kitty(0.26.5)`), and tmux 3.3 and later pass that on.
pub const KITTY_PLACEHOLDERS_SINCE: (u32, u32, u32) = (0, 28, 0);

/// kitty's version in a terminal's name (`kitty(0.26.5)`: XTVERSION's text, or
/// tmux's `client_termtype`), when the name holds one.
pub fn kitty_version(name: &str) -> Option<(u32, u32, u32)> {
    let n = name.to_ascii_lowercase();
    let inner = n[n.find("kitty(")? + "kitty(".len()..].split(')').next()?;
    let mut parts = inner.split('.').map(|p| {
        let digits: String = p.trim().chars().take_while(char::is_ascii_digit).collect();
        digits.parse::<u32>().ok()
    });
    let major = parts.next()??;
    let minor = parts.next()??;
    let patch = parts.next().flatten().unwrap_or(0);
    Some((major, minor, patch))
}

/// Whether the terminal named `name` draws kitty's Unicode placeholders: kitty
/// from [`KITTY_PLACEHOLDERS_SINCE`] by the version in its name; Ghostty and Rio
/// (taken to, as before). `None` where the name does not say: kitty without its
/// version (`xterm-kitty`), or any other name.
pub fn kitty_placeholders(name: &str) -> Option<bool> {
    let n = name.to_ascii_lowercase();
    if n.contains("kitty") {
        kitty_version(&n).map(|v| v >= KITTY_PLACEHOLDERS_SINCE)
    } else if n.contains("ghostty") || n.starts_with("rio") {
        Some(true)
    } else {
        None
    }
}

/// What [`choose`] decided.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Choice {
    pub graphics: Graphics,
    /// Why, in a few words.
    pub reason: String,
    /// Images go through tmux's passthrough (kitty placeholders, or a requested
    /// protocol that tmux does not draw).
    pub passthrough: bool,
    /// Kitty images drawn by Unicode placeholder cells (inside tmux).
    pub placeholders: bool,
    /// The inspector shows kitty frames by Unicode placeholder cells: inside tmux,
    /// and where the terminal is known to draw them ([`kitty_placeholders`]);
    /// elsewhere it places each frame directly at the view's first cell (`a=T`,
    /// which every kitty draws), and `reason` says why.
    pub kitty_placeholders: bool,
    /// One line for the status bar when the choice is a fallback: why, and what
    /// would give images.
    pub note: Option<String>,
    /// The caller asked for this protocol (no detection chose it).
    pub requested: bool,
    /// Writing a cell over an image takes the whole image away: tmux drawing
    /// sixel itself frees an image when any cell under it is written (its
    /// `image_check_area`), so text over the picture (a scale bar, a
    /// crosshair) must be drawn into its pixels instead.
    pub text_erases_images: bool,
    /// How frames are drawn in text (the `text` protocol): the symbols and the
    /// colours the terminal takes.
    pub text: TextStyle,
}

/// Decides from what was learnt: the request, the environment, the terminal's
/// answers (`None`: not asked) and, inside tmux, the server's account of the
/// outer terminal (`Err`: it could not be asked).
pub fn choose(
    requested: Protocol,
    env: &TerminalEnv,
    replies: Option<&Replies>,
    capped: bool,
    tmux: Option<&Result<TmuxInfo, String>>,
) -> Choice {
    let tmux_says = replies
        .and_then(|r| r.xtversion.as_deref())
        .is_some_and(|v| v.starts_with("tmux"));
    let in_tmux = env.in_tmux() || tmux_says;
    let tmux_info = tmux.and_then(|t| t.as_ref().ok());
    let tmux_sixel = tmux_info.is_some_and(|t| t.draws_sixel())
        || (tmux_says && replies.is_some_and(|r| r.sixel()));
    // The names the terminal goes by, most precise first: what tmux says of the
    // outer terminal inside tmux, else its own XTVERSION answer, else the
    // environment. The first that says whether it draws kitty placeholders wins.
    let names: Vec<&str> = if in_tmux {
        tmux_info
            .map(|t| vec![t.termtype.as_str(), t.termname.as_str()])
            .unwrap_or_default()
    } else {
        [
            replies.and_then(|r| r.xtversion.as_deref()),
            env.term_program.as_deref(),
            env.term.as_deref(),
        ]
        .into_iter()
        .flatten()
        .collect()
    };
    let placeholders_known = names.iter().find_map(|n| kitty_placeholders(n));
    let text = choose_text(
        &names,
        env.term.as_deref(),
        env.colorterm.as_deref(),
        tmux_info.map(|t| t.features.as_str()),
        in_tmux,
    );
    let named = names
        .iter()
        .find(|n| kitty_placeholders(n).is_some() || by_name(n).is_some())
        .copied();
    let choice = |graphics: Graphics, reason: String, note: Option<String>| {
        let kitty = graphics == Graphics::Kitty;
        // Inside tmux nothing else works: placed images do not follow the pane.
        let kitty_placeholders = kitty && (in_tmux || placeholders_known == Some(true));
        let reason = if kitty && !kitty_placeholders {
            let why = match (placeholders_known, named) {
                (Some(false), Some(n)) => format!("{n} has no Unicode placeholders"),
                (_, Some(n)) if n.to_ascii_lowercase().contains("kitty") => {
                    format!("{n} does not say its version")
                }
                (_, Some(n)) => format!("{n} is not known to draw Unicode placeholders"),
                _ => "the terminal is not known to draw Unicode placeholders".to_string(),
            };
            format!("{reason}; frames placed directly ({why}; kitty has them from 0.28)")
        } else {
            reason
        };
        let tmux_draws = in_tmux && graphics == Graphics::Sixel && tmux_sixel;
        Choice {
            graphics,
            reason,
            passthrough: in_tmux && graphics != Graphics::Halfblocks && !tmux_draws,
            text_erases_images: tmux_draws,
            placeholders: in_tmux && kitty,
            kitty_placeholders,
            note,
            requested: requested != Protocol::Auto,
            text: text.clone(),
        }
    };
    let forced = match requested {
        Protocol::Kitty => Some(Graphics::Kitty),
        Protocol::Sixel => Some(Graphics::Sixel),
        Protocol::Iterm => Some(Graphics::Iterm2),
        Protocol::Halfblocks => Some(Graphics::Halfblocks),
        Protocol::Auto => None,
    };
    if let Some(g) = forced {
        return choice(g, "requested".into(), None);
    }
    if in_tmux {
        let outer = tmux_info
            .map(|t| (t.termtype.clone(), t.termname.clone()))
            .unwrap_or_default();
        let outer_graphics = by_name(&outer.0).or_else(|| by_name(&outer.1));
        let outer_name = [outer.0.as_str(), outer.1.as_str()]
            .into_iter()
            .find(|s| !s.is_empty())
            .unwrap_or("an unknown terminal")
            .to_string();
        // A kitty older than 0.28 outside: no placeholders, and images placed
        // directly do not survive tmux (they stay put when panes scroll, switch or
        // redraw), so it is drawn as any terminal without images.
        let old_kitty =
            outer_graphics == Some(Graphics::Kitty) && placeholders_known == Some(false);
        if outer_graphics == Some(Graphics::Kitty) && !old_kitty {
            return choice(
                Graphics::Kitty,
                format!("tmux, outer terminal {outer_name}: kitty placeholders"),
                None,
            );
        }
        if tmux_sixel {
            return choice(Graphics::Sixel, "tmux draws sixel".into(), None);
        }
        let version = tmux_info.map(|t| t.version.as_str()).unwrap_or("");
        let why = match tmux {
            Some(Err(e)) => format!("tmux could not be asked ({e})"),
            _ => format!("tmux {version} in {outer_name}"),
        };
        if old_kitty {
            return choice(
                Graphics::Halfblocks,
                format!("{why}, a kitty without Unicode placeholders (from 0.28)"),
                Some(format!(
                    "text: {why}: this kitty has no Unicode placeholders (kitty has them from 0.28), and tmux cannot carry images placed directly; kitty 0.28+, or pcimg outside tmux, would draw images"
                )),
            );
        }
        return choice(
            Graphics::Halfblocks,
            why.clone(),
            Some(format!(
                "text: {why} draws no images here; kitty, Ghostty or Rio outside tmux, or tmux 3.4+ with sixel, would"
            )),
        );
    }
    if let Some(r) = replies {
        if let Some((g, v)) = r
            .xtversion
            .as_deref()
            .and_then(|v| by_name(v).map(|g| (g, v)))
        {
            return choice(g, format!("the terminal says it is {v}"), None);
        }
        if r.kitty_ok() {
            return choice(
                Graphics::Kitty,
                "the kitty graphics query was answered OK".into(),
                None,
            );
        }
        if r.sixel() {
            return choice(
                Graphics::Sixel,
                "DA1 lists sixel (attribute 4)".into(),
                None,
            );
        }
    }
    if let Some((g, why)) = env.hint() {
        return choice(g, why, None);
    }
    let note = if capped {
        format!(
            "text: the terminal did not answer within {} ms",
            probe::CAP.as_millis()
        )
    } else if replies.is_none() {
        "text: stdin or stdout is not a terminal, so it was not asked".into()
    } else {
        "text: the terminal reports no image protocol".into()
    };
    choice(
        Graphics::Halfblocks,
        "no image protocol found".into(),
        Some(note),
    )
}

/// Everything detection learnt, and what it chose: what `pcimg doctor` prints.
#[derive(Debug, Clone, Serialize)]
pub struct Detection {
    #[serde(flatten)]
    pub choice: Choice,
    /// Pixels per cell for frames (1×2 for half-blocks).
    pub cell_pixels: (u32, u32),
    /// Where the cell size came from.
    pub cell_source: &'static str,
    /// What was asked of the terminal, printable.
    pub asked: Option<String>,
    pub probe: Option<Probe>,
    pub tmux: Option<Result<TmuxInfo, String>>,
    pub winsize: Option<WinSize>,
    pub env: TerminalEnv,
    /// Milliseconds the whole detection took.
    pub millis: f64,
}

impl Detection {
    /// Keys typed during the probe, for the inspector.
    pub fn typed(&self) -> &[u8] {
        self.probe.as_ref().map_or(&[], |p| &p.typed)
    }

    /// The tmux pane to allow passthrough in, when images go through it.
    pub(crate) fn passthrough_pane(&self) -> Option<&str> {
        if !self.choice.passthrough {
            return None;
        }
        match &self.tmux {
            Some(Ok(t)) if !t.pane.is_empty() => Some(t.pane.as_str()),
            _ => self.env.tmux_pane.as_deref(),
        }
    }

    /// Draws text frames with `set` (`--symbols`), whatever the terminal's
    /// name suggested.
    pub fn use_symbols(&mut self, set: SymbolSet) {
        self.choice.text.set = set;
        self.choice.text.reason = format!("{} ({set} requested)", self.choice.text.depth.name());
        if self.choice.graphics == Graphics::Halfblocks {
            self.cell_pixels = text_cell(set);
        }
    }

    /// Turns on `allow-passthrough` for our pane when images need it; on failure
    /// the note says so. Undone by [`tmux::restore_passthrough`].
    pub fn prepare(&mut self) {
        if let Some(pane) = self.passthrough_pane().map(str::to_string)
            && let Err(e) = tmux::allow_passthrough(&pane)
        {
            self.choice.note = Some(format!("cannot allow passthrough in tmux: {e}"));
        }
    }
}

/// Pixels a text cell is rendered at: the symbol grid, doubled each way so
/// that each sub-cell is the mean of four rendered pixels (a point between
/// sub-cells still lands in one).
fn text_cell(set: SymbolSet) -> (u32, u32) {
    let (w, h) = set.grid();
    (2 * w as u32, 2 * h as u32)
}

/// The cell size: the kernel's (`TIOCGWINSZ`) when plausible, else tmux's account
/// of the outer terminal, else the terminal's `CSI 16 t` answer, else 10×20.
pub(crate) fn cell_size(
    graphics: Graphics,
    winsize: Option<&WinSize>,
    tmux: Option<&TmuxInfo>,
    replies: Option<&Replies>,
) -> ((u32, u32), &'static str) {
    if graphics == Graphics::Halfblocks {
        return ((1, 2), "text");
    }
    if let Some(c) = winsize.and_then(|w| w.cell_pixels()) {
        return (c, "TIOCGWINSZ");
    }
    if let Some(c) = tmux.and_then(|t| t.cell_pixels) {
        return (c, "tmux client_cell_width/height");
    }
    if let Some(c) = replies
        .and_then(|r| r.cell_pixels)
        .and_then(probe::plausible_cell)
    {
        return (c, "CSI 16 t");
    }
    ((10, 20), "assumed 10×20")
}

/// Learns what it can about the terminal on stdin/stdout and chooses. Asks the
/// terminal (at most `cap`) only when both are a terminal and we are not in tmux
/// (there the tmux server is asked instead); with `--protocol` given and the
/// cell size known, asks nothing.
pub fn detect(requested: Protocol, cap: Duration) -> Detection {
    let start = Instant::now();
    let env = TerminalEnv::from_process();
    // The terminal: stdin and stdout, or the controlling terminal when they are
    // redirected (`pcimg doctor > report.txt`).
    let tty_file = if std::io::stdin().is_terminal() && std::io::stdout().is_terminal() {
        None
    } else {
        std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open("/dev/tty")
            .ok()
    };
    let (fd_in, fd_out) = match &tty_file {
        Some(f) => (f.as_raw_fd(), f.as_raw_fd()),
        None => (libc::STDIN_FILENO, libc::STDOUT_FILENO),
    };
    let tty =
        tty_file.is_some() || (std::io::stdin().is_terminal() && std::io::stdout().is_terminal());
    let winsize = WinSize::of(fd_out);
    let mut tmux_result = None;
    let mut probe_result = None;
    let mut asked = None;
    if env.in_tmux() {
        tmux_result = Some(tmux::query(env.tmux_pane.as_deref()));
    } else if tty {
        let known = requested != Protocol::Auto
            && (requested == Protocol::Halfblocks
                || winsize.as_ref().and_then(|w| w.cell_pixels()).is_some());
        if !known {
            asked = Some(super::replies::escaped(
                super::replies::queries().as_bytes(),
            ));
            match probe::run(fd_in, fd_out, cap) {
                Ok(p) => {
                    if p.replies
                        .xtversion
                        .as_deref()
                        .is_some_and(|v| v.starts_with("tmux"))
                    {
                        tmux_result = Some(tmux::query(None));
                    }
                    probe_result = Some(p);
                }
                Err(e) => {
                    asked = Some(format!("{} (failed: {e})", asked.unwrap_or_default()));
                }
            }
        }
    }
    let replies = probe_result.as_ref().map(|p| &p.replies);
    let capped = probe_result.as_ref().is_some_and(|p| p.capped);
    let choice = choose(requested, &env, replies, capped, tmux_result.as_ref());
    let (mut cell_pixels, cell_source) = cell_size(
        choice.graphics,
        winsize.as_ref(),
        tmux_result.as_ref().and_then(|t| t.as_ref().ok()),
        replies,
    );
    if choice.graphics == Graphics::Halfblocks {
        cell_pixels = text_cell(choice.text.set);
    }
    Detection {
        choice,
        cell_pixels,
        cell_source,
        asked,
        probe: probe_result,
        tmux: tmux_result,
        winsize,
        env,
        millis: start.elapsed().as_secs_f64() * 1e3,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A terminal outside tmux that answered XTVERSION with `name`, the kitty query
    /// OK and DA1.
    fn answered(name: Option<&str>) -> Replies {
        Replies {
            xtversion: name.map(String::from),
            kitty: Some("OK".into()),
            cell_pixels: Some((10, 20)),
            da1: Some(vec![62]),
        }
    }

    fn outside(name: Option<&str>) -> Choice {
        let env = TerminalEnv {
            term: Some("xterm-kitty".into()),
            ..Default::default()
        };
        choose(Protocol::Auto, &env, Some(&answered(name)), false, None)
    }

    /// Inside tmux, with the outer terminal as tmux saw it.
    fn in_tmux(termtype: &str, termname: &str, features: &str) -> Choice {
        let env = TerminalEnv {
            term: Some("tmux-256color".into()),
            tmux: Some("/tmp/tmux-0/default,1,0".into()),
            tmux_pane: Some("%1".into()),
            ..Default::default()
        };
        let info = TmuxInfo {
            termtype: termtype.into(),
            termname: termname.into(),
            features: features.into(),
            version: "3.3a".into(),
            pane: "%1".into(),
            ..Default::default()
        };
        choose(Protocol::Auto, &env, None, false, Some(&Ok(info)))
    }

    #[test]
    fn kittys_version_is_read_from_its_name() {
        assert_eq!(kitty_version("kitty(0.26.5)"), Some((0, 26, 5)));
        assert_eq!(kitty_version("kitty(0.28.0)"), Some((0, 28, 0)));
        assert_eq!(kitty_version("kitty(0.21.2)"), Some((0, 21, 2)));
        assert_eq!(kitty_version("kitty(0.35.2)"), Some((0, 35, 2)));
        assert_eq!(kitty_version("Kitty(0.30)"), Some((0, 30, 0)));
        assert_eq!(kitty_version("kitty(0.36.4-dev)"), Some((0, 36, 4)));
        for unknown in [
            "xterm-kitty",
            "kitty",
            "kitty()",
            "kitty(x.y)",
            "kitty(1)",
            "",
        ] {
            assert_eq!(kitty_version(unknown), None, "{unknown}");
        }
        // Placeholders from 0.28.0 on; unknown where the name does not say.
        assert_eq!(kitty_placeholders("kitty(0.26.5)"), Some(false));
        assert_eq!(kitty_placeholders("kitty(0.21.2)"), Some(false));
        assert_eq!(kitty_placeholders("kitty(0.27.1)"), Some(false));
        assert_eq!(kitty_placeholders("kitty(0.28.0)"), Some(true));
        assert_eq!(kitty_placeholders("kitty(1.0.0)"), Some(true));
        assert_eq!(kitty_placeholders("xterm-kitty"), None);
        assert_eq!(kitty_placeholders("ghostty 1.1.3"), Some(true));
        assert_eq!(kitty_placeholders("XTerm(379)"), None);
    }

    #[test]
    fn kitty_gets_placeholders_only_from_0_28_and_direct_placement_before() {
        for (name, placeholders) in [
            ("kitty(0.26.5)", false),
            ("kitty(0.21.2)", false),
            ("kitty(0.28.0)", true),
            ("kitty(0.35.2)", true),
        ] {
            let c = outside(Some(name));
            assert_eq!(c.graphics, Graphics::Kitty, "{name}");
            assert_eq!(c.kitty_placeholders, placeholders, "{name}: {c:?}");
            assert!(!c.passthrough && !c.placeholders, "{name}");
            assert_eq!(c.reason.contains("placed directly"), !placeholders, "{c:?}");
        }
        let c = outside(Some("kitty(0.26.5)"));
        assert!(
            c.reason
                .contains("kitty(0.26.5) has no Unicode placeholders"),
            "{}",
            c.reason
        );
        // Unknown version (no XTVERSION answer: kitty before 0.21.2, or another
        // terminal answering the kitty query): placed directly, which all draw.
        let c = outside(None);
        assert_eq!(c.graphics, Graphics::Kitty);
        assert!(!c.kitty_placeholders);
        assert!(
            c.reason.contains("xterm-kitty does not say its version"),
            "{}",
            c.reason
        );
        // Only the environment (the terminal was not asked): the same.
        let env = TerminalEnv {
            kitty_window_id: Some("1".into()),
            ..Default::default()
        };
        let c = choose(Protocol::Auto, &env, None, false, None);
        assert_eq!((c.graphics, c.kitty_placeholders), (Graphics::Kitty, false));
        // --protocol kitty on a terminal with a known version follows it.
        let env = TerminalEnv::default();
        let r = answered(Some("kitty(0.35.2)"));
        let c = choose(Protocol::Kitty, &env, Some(&r), false, None);
        assert!(c.kitty_placeholders);
        let r = answered(Some("WezTerm 20240203-110809-5046fc22"));
        let c = choose(Protocol::Kitty, &env, Some(&r), false, None);
        assert!(!c.kitty_placeholders, "WezTerm has no placeholders");
        // Ghostty and Rio keep them, as before.
        for name in ["ghostty 1.1.3", "Rio 0.2.10"] {
            let c = outside(Some(name));
            assert_eq!(c.graphics, Graphics::Kitty, "{name}");
            assert!(c.kitty_placeholders, "{name}");
        }
        // Other protocols have none.
        let r = Replies {
            kitty: None,
            da1: Some(vec![63, 4]),
            ..answered(Some("XTerm(379)"))
        };
        let c = choose(
            Protocol::Auto,
            &TerminalEnv::default(),
            Some(&r),
            false,
            None,
        );
        assert_eq!((c.graphics, c.kitty_placeholders), (Graphics::Sixel, false));
    }

    #[test]
    fn inside_tmux_an_old_kitty_outside_falls_back_and_says_why() {
        let c = in_tmux("kitty(0.26.5)", "xterm-kitty", "");
        assert_eq!(c.graphics, Graphics::Halfblocks, "{c:?}");
        assert!(!c.passthrough && !c.placeholders && !c.kitty_placeholders);
        let note = c.note.unwrap();
        assert!(
            note.starts_with(
                "text: tmux 3.3a in kitty(0.26.5): this kitty has no Unicode placeholders"
            ),
            "{note}"
        );
        assert!(note.contains("would"), "{note}");
        // A new kitty outside: placeholders through passthrough, as before.
        let c = in_tmux("kitty(0.35.2)", "xterm-kitty", "");
        assert_eq!(c.graphics, Graphics::Kitty);
        assert!(c.passthrough && c.placeholders && c.kitty_placeholders);
        assert!(c.note.is_none());
        // tmux older than 3.3 does not say the version: as before.
        let c = in_tmux("", "xterm-kitty", "");
        assert_eq!(c.graphics, Graphics::Kitty);
        assert!(c.placeholders && c.kitty_placeholders);
        // An old kitty, but tmux draws sixel itself: sixel.
        let c = in_tmux("kitty(0.21.2)", "xterm-kitty", "RGB,sixel");
        assert_eq!(c.graphics, Graphics::Sixel);
    }
    #[test]
    fn the_environment_decides_where_the_terminal_was_not_asked() {
        let env = |f: fn(&mut TerminalEnv)| {
            let mut e = TerminalEnv::default();
            f(&mut e);
            choose(Protocol::Auto, &e, None, false, None)
        };
        let c = env(|e| e.term_program = Some("WezTerm".into()));
        assert_eq!(c.graphics, Graphics::Iterm2, "{c:?}");
        assert!(c.reason.contains("TERM_PROGRAM=WezTerm"), "{}", c.reason);
        let c = env(|e| e.lc_terminal = Some("iTerm2".into()));
        assert_eq!(c.graphics, Graphics::Iterm2);
        assert_eq!(c.reason, "LC_TERMINAL=iTerm2");
        let c = env(|e| e.term = Some("mlterm".into()));
        assert_eq!(c.graphics, Graphics::Sixel, "{c:?}");
        let c = env(|e| e.term = Some("xterm-256color".into()));
        assert_eq!(c.graphics, Graphics::Halfblocks);
        assert!(!c.requested);
        let note = c.note.unwrap();
        assert!(
            note.contains("not a terminal, so it was not asked"),
            "{note}"
        );
        // Asked: silent until the cap, or answering with no image protocol.
        let asked = |r: Replies, capped: bool| {
            let c = choose(
                Protocol::Auto,
                &TerminalEnv::default(),
                Some(&r),
                capped,
                None,
            );
            assert_eq!(c.graphics, Graphics::Halfblocks);
            c.note.unwrap()
        };
        assert!(asked(Replies::default(), true).contains("did not answer within"));
        let da1 = Replies {
            da1: Some(vec![62, 22]),
            ..Default::default()
        };
        assert!(asked(da1, false).contains("reports no image protocol"));
    }

    #[test]
    fn a_requested_protocol_wins_and_says_so() {
        for (p, g) in [
            (Protocol::Kitty, Graphics::Kitty),
            (Protocol::Sixel, Graphics::Sixel),
            (Protocol::Iterm, Graphics::Iterm2),
            (Protocol::Halfblocks, Graphics::Halfblocks),
        ] {
            // Whatever the terminal answered.
            let r = answered(Some("XTerm(379)"));
            let c = choose(p, &TerminalEnv::default(), Some(&r), false, None);
            assert_eq!(c.graphics, g);
            assert!(c.requested && c.note.is_none(), "{c:?}");
            assert!(c.reason.starts_with("requested"), "{}", c.reason);
        }
        // Inside tmux a requested sixel goes through passthrough (tmux 3.3a
        // draws none itself).
        let env = tmux_env();
        let info = Ok(TmuxInfo::default());
        let c = choose(Protocol::Sixel, &env, None, false, Some(&info));
        assert!(c.requested && c.passthrough, "{c:?}");
    }

    #[test]
    fn tmux_that_draws_sixel_gets_it_without_passthrough() {
        let c = in_tmux("XTerm(379)", "xterm", "256,RGB,sixel,title");
        assert_eq!(c.graphics, Graphics::Sixel, "{c:?}");
        assert!(!c.passthrough && c.note.is_none());
        assert_eq!(c.reason, "tmux draws sixel");
        // And frees the image when a cell over it is written.
        assert!(c.text_erases_images);
        // Without the feature: half-blocks, and the note says what would draw.
        let c = in_tmux("XTerm(379)", "xterm", "256,RGB,title");
        assert_eq!(c.graphics, Graphics::Halfblocks);
        let note = c.note.unwrap();
        assert!(
            note.contains("tmux 3.3a in XTerm(379)") && note.contains("would"),
            "{note}"
        );
    }

    /// The environment inside tmux, and nothing else.
    fn tmux_env() -> TerminalEnv {
        TerminalEnv {
            tmux: Some("/tmp/tmux-0/default,1,0".into()),
            ..Default::default()
        }
    }

    #[test]
    fn tmux_that_cannot_be_asked_is_said() {
        let env = tmux_env();
        let failed = Err("tmux: no server running".to_string());
        let c = choose(Protocol::Auto, &env, None, false, Some(&failed));
        assert_eq!(c.graphics, Graphics::Halfblocks);
        assert_eq!(
            c.reason,
            "tmux could not be asked (tmux: no server running)"
        );
        assert!(c.note.unwrap().contains("tmux could not be asked"));
    }
}
