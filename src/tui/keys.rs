//! The inspector's key map: which key does what ([`command_for`]), and the same
//! table as text for the `?` help overlay ([`HELP`]). Only this file knows keys;
//! the state machine in `app.rs` works on [`Command`]s.

use crossterm::event::{KeyCode, KeyEvent, KeyEventKind, KeyModifiers};

/// Something the user asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    /// Orbit by (yaw, pitch) steps: +1 turns right / up.
    Orbit(i8, i8),
    /// Pan by (right, up) steps.
    Pan(i8, i8),
    /// Zoom in (+1) or out (-1).
    Zoom(i8),
    ResetView,
    /// Pin one pyramid level (0 = finest).
    PinLevel(usize),
    /// Automatic level choice (view-dependent under the point budget).
    Automatic,
    Coarser,
    Finer,
    CycleColor,
    /// Colour by classification.
    ColorClasses,
    CyclePointSize,
    ToggleEdl,
    /// Eye-dome lighting stronger (+1) or weaker (-1).
    EdlStrength(i8),
    /// Eye-dome lighting radius 1 → 2 → 3 → 4.
    EdlRadius,
    /// Pick mode on / off: a crosshair the arrows move.
    TogglePick,
    /// Pick the point under the crosshair.
    Pick,
    /// Pick at a place in the view (a mouse click), as fractions across and down.
    PickAt(f32, f32),
    /// Forget the picked points.
    ClearPicks,
    /// Select the previous (-1) or next legend row.
    LegendRow(i8),
    /// Show or hide the selected legend row's class.
    ToggleClass,
    /// Select legend row N and show or hide its class (a click on the row).
    ToggleClassRow(usize),
    /// A section through the last pick, seen from the side, on / off.
    ToggleSection,
    /// `o`: the clip box on / off (the `--clip` box, or the middle of the data).
    ToggleClip,
    /// The section's slab thicker (+1) or thinner (-1).
    SlabWidth(i8),
    /// The section's slab moved forward (+1) or back by its thickness.
    SlabMove(i8),
    /// The section's plane turned about the vertical by 15° (+1: anticlockwise).
    SlabTurn(i8),
    /// Colour by the next band (`band:NAME`), through all the data's bands.
    CycleBand,
    BudgetDown,
    BudgetUp,
    /// Switch between the distance rule and view-dependent selection.
    ToggleDistanceRule,
    SaveFrame,
    NextPart,
    PreviousPart,
    ToggleHelp,
    /// `q` or Esc: closes the help if it is open, else quits.
    Quit,
    /// Ctrl-C: quits at once.
    Interrupt,
    /// Ctrl-Z: hands the terminal back to the shell until `fg`.
    Suspend,
    /// Ctrl-L: draws the whole screen again.
    Repaint,
}

/// The command for a key press, if any. Releases and repeats of non-movement
/// keys are ignored by the caller through [`KeyEvent::kind`].
pub fn command_for(key: KeyEvent) -> Option<Command> {
    if key.kind == KeyEventKind::Release {
        return None;
    }
    let shift = key.modifiers.contains(KeyModifiers::SHIFT);
    let ctrl = key.modifiers.contains(KeyModifiers::CONTROL);
    use Command::*;
    Some(match key.code {
        KeyCode::Char('c') | KeyCode::Char('C') if ctrl => Interrupt,
        KeyCode::Char('z') | KeyCode::Char('Z') if ctrl => Suspend,
        KeyCode::Char('l') | KeyCode::Char('L') if ctrl => Repaint,
        // Other control chords are not the plain letter's command.
        KeyCode::Char(_) if ctrl => return None,
        KeyCode::Char('q') | KeyCode::Esc => Quit,
        KeyCode::Left if shift => Pan(-1, 0),
        KeyCode::Right if shift => Pan(1, 0),
        KeyCode::Up if shift => Pan(0, 1),
        KeyCode::Down if shift => Pan(0, -1),
        KeyCode::Left | KeyCode::Char('h') => Orbit(-1, 0),
        KeyCode::Right | KeyCode::Char('l') => Orbit(1, 0),
        KeyCode::Up | KeyCode::Char('k') => Orbit(0, 1),
        KeyCode::Down | KeyCode::Char('j') => Orbit(0, -1),
        KeyCode::Char('a') => Automatic,
        KeyCode::Char('w') => Pan(0, 1),
        KeyCode::Char('s') => SaveFrame,
        KeyCode::Char('S') => Pan(0, -1),
        KeyCode::Char('A') => Pan(-1, 0),
        KeyCode::Char('d') | KeyCode::Char('D') => Pan(1, 0),
        KeyCode::Char('W') => Pan(0, 1),
        KeyCode::Char('+') | KeyCode::Char('=') => Zoom(1),
        KeyCode::Char('-') | KeyCode::Char('_') => Zoom(-1),
        KeyCode::Char('r') => ResetView,
        KeyCode::Char(c @ '0'..='9') => PinLevel(c as usize - '0' as usize),
        KeyCode::Char('[') => Coarser,
        KeyCode::Char(']') => Finer,
        KeyCode::Char('c') => CycleColor,
        KeyCode::Char('C') => ColorClasses,
        KeyCode::Char('p') => CyclePointSize,
        KeyCode::Char('e') => ToggleEdl,
        KeyCode::Char('E') => EdlRadius,
        KeyCode::Char('<') => EdlStrength(-1),
        KeyCode::Char('>') => EdlStrength(1),
        KeyCode::Char('x') => TogglePick,
        KeyCode::Enter => Pick,
        KeyCode::Char('X') => ClearPicks,
        KeyCode::Char(',') => LegendRow(-1),
        KeyCode::Char('.') => LegendRow(1),
        KeyCode::Char(' ') => ToggleClass,
        KeyCode::Char('z') => ToggleSection,
        KeyCode::Char('o') => ToggleClip,
        KeyCode::Char('(') => SlabWidth(-1),
        KeyCode::Char(')') => SlabWidth(1),
        KeyCode::Char('{') => SlabMove(-1),
        KeyCode::Char('}') => SlabMove(1),
        KeyCode::Char('/') => SlabTurn(1),
        KeyCode::Char('\\') => SlabTurn(-1),
        KeyCode::Char('v') => CycleBand,
        KeyCode::Char('b') => BudgetDown,
        KeyCode::Char('B') => BudgetUp,
        KeyCode::Char('m') => ToggleDistanceRule,
        KeyCode::Tab | KeyCode::Char('n') => NextPart,
        KeyCode::BackTab => PreviousPart,
        KeyCode::Char('?') => ToggleHelp,
        _ => return None,
    })
}

/// The key map as (keys, what they do), for the help overlay and docs/guide.md.
pub const HELP: &[(&str, &str)] = &[
    ("←→↑↓ / h l k j", "orbit around the centre"),
    (
        "shift+arrows / W A S D",
        "pan (lower-case a and s: automatic, save)",
    ),
    ("+ / -", "zoom in / out"),
    ("r", "reset the view"),
    ("0 … 9", "pin a pyramid level (0 = finest)"),
    ("a", "automatic level choice"),
    ("[ / ]", "coarser / finer level"),
    ("m", "distance rule ↔ view-dependent"),
    ("b / B", "halve / double the point budget"),
    (
        "c / C",
        "cycle colour: rgb, intensity, height, classification, level, part / classification",
    ),
    (
        ", / . , space",
        "legend: select the previous / next class, show or hide it",
    ),
    (
        "x, Enter, click",
        "pick mode (arrows move the crosshair), pick the point there",
    ),
    ("X", "forget the picks (two picks give their distances)"),
    (
        "v",
        "colour by the next band (band:NAME, every band in turn), ramp legend",
    ),
    (
        "z",
        "section through the two last picks (or the last, across the view), from the side, on / off",
    ),
    (
        "( / ) , { / } , / \\",
        "section slab thinner / thicker, back / forward, turn it 15° left / right",
    ),
    (
        "o",
        "clip box on / off; without a section ( ) size it, { } move it, / \\ choose its axis",
    ),
    ("p", "point size 1 → 2 → 3"),
    (
        "e, < / >, E",
        "eye-dome lighting on / off, weaker / stronger, radius 1 → 4",
    ),
    ("s", "save the current frame as PNG"),
    ("Tab / n, Shift-Tab", "select the next / previous part"),
    ("?", "this help (q or Esc closes it)"),
    (
        "Ctrl-Z / Ctrl-L",
        "suspend to the shell (fg resumes) / repaint",
    ),
    ("q / Esc / Ctrl-C", "quit"),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn key(code: KeyCode, m: KeyModifiers) -> KeyEvent {
        KeyEvent::new(code, m)
    }

    #[test]
    fn the_documented_keys_map_to_commands() {
        let none = KeyModifiers::NONE;
        assert_eq!(
            command_for(key(KeyCode::Char('3'), none)),
            Some(Command::PinLevel(3))
        );
        assert_eq!(
            command_for(key(KeyCode::Left, KeyModifiers::SHIFT)),
            Some(Command::Pan(-1, 0))
        );
        assert_eq!(
            command_for(key(KeyCode::Left, none)),
            Some(Command::Orbit(-1, 0))
        );
        assert_eq!(
            command_for(key(KeyCode::Char('c'), KeyModifiers::CONTROL)),
            Some(Command::Interrupt)
        );
        assert_eq!(
            command_for(key(KeyCode::Char('c'), none)),
            Some(Command::CycleColor)
        );
        assert_eq!(
            command_for(key(KeyCode::Tab, none)),
            Some(Command::NextPart)
        );
        assert_eq!(command_for(key(KeyCode::Char('Q'), none)), None);
        assert_eq!(
            command_for(key(KeyCode::Char('x'), none)),
            Some(Command::TogglePick)
        );
        assert_eq!(command_for(key(KeyCode::Enter, none)), Some(Command::Pick));
        assert_eq!(
            command_for(key(KeyCode::Char(' '), none)),
            Some(Command::ToggleClass)
        );
        assert_eq!(
            command_for(key(KeyCode::BackTab, KeyModifiers::SHIFT)),
            Some(Command::PreviousPart)
        );
        let ctrl = KeyModifiers::CONTROL;
        assert_eq!(
            command_for(key(KeyCode::Char('z'), ctrl)),
            Some(Command::Suspend)
        );
        assert_eq!(
            command_for(key(KeyCode::Char('l'), ctrl)),
            Some(Command::Repaint)
        );
        assert_eq!(command_for(key(KeyCode::Char('s'), ctrl)), None);
        let mut release = key(KeyCode::Char('q'), none);
        release.kind = KeyEventKind::Release;
        assert_eq!(command_for(release), None);
    }
}
