//! `pcimg doctor`: what the terminal was asked, what it answered and how fast,
//! and which image protocol and cell size `preview` and `inspect` would use: the
//! text a user pastes into a bug report.

use crate::term::{self, Detection, Protocol};
use std::fmt::Write as _;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Detect as `--protocol` would (auto asks the terminal).
    #[arg(long, default_value = "auto")]
    pub protocol: Protocol,
    /// Print the whole detection as JSON instead.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let found = term::detect(a.protocol, term::probe::CAP);
    if a.json {
        return super::print_out(&format!("{}\n", serde_json::to_string_pretty(&found)?));
    }
    super::print_out(&report(&found))
}

/// The detection for people.
pub fn report(d: &Detection) -> String {
    let mut s = String::new();
    let c = &d.choice;
    let _ = writeln!(
        s,
        "image protocol: {} ({})",
        c.graphics.name(),
        crate::advice::protocol_reason(c)
    );
    if c.passthrough {
        let _ = writeln!(
            s,
            "  through tmux passthrough{}",
            if c.placeholders {
                ", as Unicode placeholders"
            } else {
                ""
            }
        );
    }
    if c.graphics == term::Graphics::Kitty && !c.passthrough {
        let _ = writeln!(
            s,
            "  inspect: {}",
            if c.kitty_placeholders {
                "frames drawn by Unicode placeholder cells"
            } else {
                "frames placed directly at the view's first cell"
            }
        );
    }
    if let Some(n) = crate::advice::protocol_note(c) {
        let _ = writeln!(s, "  note: {n}");
    }
    // Where images are drawn, text is the fallback (`--protocol text`).
    let _ = writeln!(
        s,
        "text: {}, {} (--symbols to choose)",
        c.text.set, c.text.reason
    );
    let _ = writeln!(
        s,
        "cell size: {}×{} px ({})",
        d.cell_pixels.0, d.cell_pixels.1, d.cell_source
    );
    if let Some(w) = &d.winsize {
        let _ = writeln!(
            s,
            "window: {}×{} cells, {}×{} px (TIOCGWINSZ)",
            w.cols, w.rows, w.width_px, w.height_px
        );
    }
    match (&d.asked, &d.probe) {
        (Some(q), Some(p)) => {
            let _ = writeln!(s, "asked the terminal: {q}");
            for (ms, a) in &p.answers {
                let _ = writeln!(s, "  {ms:7.1} ms  {a}");
            }
            let _ = writeln!(
                s,
                "  {}: {:.1} ms",
                if p.capped {
                    "no DA1 answer, gave up after"
                } else {
                    "all answered in"
                },
                p.millis
            );
        }
        (Some(q), None) => {
            let _ = writeln!(s, "asked the terminal: {q}");
        }
        _ => {
            let _ = writeln!(s, "the terminal was not asked");
        }
    }
    match &d.tmux {
        Some(Ok(t)) => {
            let _ = writeln!(
                s,
                "tmux {} (pane {}), asked in {:.1} ms: outer terminal {:?} (TERM {:?}), features {:?}, cell {}",
                t.version,
                t.pane,
                t.millis,
                t.termtype,
                t.termname,
                t.features,
                t.cell_pixels
                    .map_or("not reported".to_string(), |(w, h)| format!("{w}×{h} px"))
            );
        }
        Some(Err(e)) => {
            let _ = writeln!(s, "tmux: {e}");
        }
        None => {}
    }
    let e = &d.env;
    let show = |v: &Option<String>| crate::text::sanitize(v.as_deref().unwrap_or("-"));
    let _ = writeln!(
        s,
        "environment: TERM={} TERM_PROGRAM={} LC_TERMINAL={} KITTY_WINDOW_ID={} TMUX={}",
        show(&e.term),
        show(&e.term_program),
        show(&e.lc_terminal),
        show(&e.kitty_window_id),
        show(&e.tmux)
    );
    let _ = writeln!(s, "detection took {:.1} ms", d.millis);
    s
}
