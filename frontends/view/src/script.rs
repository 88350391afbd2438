//! Replayable input scripts (`--script FILE`).
//!
//! One command per line; `#` starts a comment; blank lines are ignored; words are
//! separated by spaces or tabs:
//!
//! ```text
//! drag BUTTON DX DY [STEPS]  # BUTTON = left (rotate) | right (window/level) | middle (pan);
//!                            # DX, DY whole pixels; spread over STEPS frames (default:
//!                            # one frame per 4 pixels of the longer side, at least 1)
//! wheel N                    # N wheel notches about the window centre (+ zooms in)
//! key NAME [COUNT]           # a key press, COUNT times, one per frame (names below)
//! wait MS                    # no input for MS milliseconds (refinement proceeds)
//! settle                     # wait until the full-quality frame of the view is shown
//! ```
//!
//! Key names: `left right up down + - r tab shift+tab 1 2 3 4 5 [ ] , . 0 l m w d s p h q`
//! (also `esc`, `=`, `pageup`, `pagedown`, `f1`). Input frames come at the window's
//! rate (60 per second), so `drag left 360 0 120` is a two-second, 180° turn. When the
//! script ends the viewer settles, writes `--dump` and exits.

use crate::state::{Button, Input, ViewKey};
use std::fmt;
use std::time::{Duration, Instant};

/// One script command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    Drag {
        button: Button,
        dx: i64,
        dy: i64,
        steps: u32,
    },
    Wheel(f64),
    Key(ViewKey, u32),
    Wait(Duration),
    Settle,
}

/// A parse error with its 1-based line number.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParseError {
    pub line: usize,
    pub message: String,
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "script line {}: {}", self.line, self.message)
    }
}

impl std::error::Error for ParseError {}

/// Largest accepted drag (pixels), step count, repeat count and wait (ms).
const MAX_PIXELS: i64 = 1_000_000;
const MAX_STEPS: u32 = 100_000;
const MAX_WAIT_MS: u64 = 600_000;

/// Parses a script.
pub fn parse(text: &str) -> Result<Vec<Command>, ParseError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let body = raw.split('#').next().unwrap_or("");
        let words: Vec<&str> = body.split_whitespace().collect();
        let Some((&cmd, args)) = words.split_first() else {
            continue;
        };
        let err = |message: String| ParseError { line, message };
        let arity = |lo: usize, hi: usize, usage: &str| {
            if args.len() < lo || args.len() > hi {
                Err(err(format!("usage: {usage}")))
            } else {
                Ok(())
            }
        };
        let c = match cmd.to_ascii_lowercase().as_str() {
            "drag" => {
                arity(3, 4, "drag left|right|middle DX DY [STEPS]")?;
                let button = match args[0].to_ascii_lowercase().as_str() {
                    "left" => Button::Left,
                    "right" => Button::Right,
                    "middle" => Button::Middle,
                    b => return Err(err(format!("unknown button '{b}' (left, right, middle)"))),
                };
                let px = |s: &str, what: &str| -> Result<i64, ParseError> {
                    s.parse::<i64>()
                        .ok()
                        .filter(|v| v.abs() <= MAX_PIXELS)
                        .ok_or_else(|| err(format!("{what} '{s}' is not a whole number of pixels")))
                };
                let dx = px(args[1], "DX")?;
                let dy = px(args[2], "DY")?;
                let steps =
                    match args.get(3) {
                        Some(s) => s
                            .parse::<u32>()
                            .ok()
                            .filter(|&n| (1..=MAX_STEPS).contains(&n))
                            .ok_or_else(|| err(format!("STEPS '{s}' must be 1..={MAX_STEPS}")))?,
                        None => ((dx.abs().max(dy.abs()) as u64).div_ceil(4))
                            .clamp(1, MAX_STEPS as u64) as u32,
                    };
                Command::Drag {
                    button,
                    dx,
                    dy,
                    steps,
                }
            }
            "wheel" => {
                arity(1, 1, "wheel N")?;
                let n = args[0]
                    .parse::<f64>()
                    .ok()
                    .filter(|n| n.is_finite() && n.abs() <= 1000.0)
                    .ok_or_else(|| err(format!("N '{}' is not a number of notches", args[0])))?;
                Command::Wheel(n)
            }
            "key" => {
                arity(1, 2, "key NAME [COUNT]")?;
                let k = ViewKey::from_name(args[0])
                    .ok_or_else(|| err(format!("unknown key '{}'", args[0])))?;
                let count = match args.get(1) {
                    Some(s) => s
                        .parse::<u32>()
                        .ok()
                        .filter(|&n| (1..=MAX_STEPS).contains(&n))
                        .ok_or_else(|| err(format!("COUNT '{s}' must be 1..={MAX_STEPS}")))?,
                    None => 1,
                };
                Command::Key(k, count)
            }
            "wait" => {
                arity(1, 1, "wait MS")?;
                let ms = args[0]
                    .parse::<u64>()
                    .ok()
                    .filter(|&m| m <= MAX_WAIT_MS)
                    .ok_or_else(|| err(format!("MS '{}' must be 0..={MAX_WAIT_MS}", args[0])))?;
                Command::Wait(Duration::from_millis(ms))
            }
            "settle" => {
                arity(0, 0, "settle")?;
                Command::Settle
            }
            other => return Err(err(format!("unknown command '{other}'"))),
        };
        out.push(c);
    }
    Ok(out)
}

/// What the script wants this frame.
#[derive(Clone, Debug, PartialEq)]
pub enum Tick {
    /// Inputs for this frame.
    Inputs(Vec<Input>),
    /// Nothing this frame (waiting or settling).
    Wait,
    /// The script is over.
    Done,
}

/// Replays commands, one input frame per [`Player::tick`].
pub struct Player {
    cmds: Vec<Command>,
    pos: usize,
    step: u32,
    deadline: Option<Instant>,
}

impl Player {
    pub fn new(cmds: Vec<Command>) -> Self {
        Player {
            cmds,
            pos: 0,
            step: 0,
            deadline: None,
        }
    }

    /// The inputs of the next frame at time `now`; `settled` tells whether the
    /// full-quality frame of the current view is on screen.
    pub fn tick(&mut self, now: Instant, settled: bool) -> Tick {
        loop {
            let Some(&cmd) = self.cmds.get(self.pos) else {
                return Tick::Done;
            };
            match cmd {
                Command::Drag {
                    button,
                    dx,
                    dy,
                    steps,
                } => {
                    // Whole-pixel moves whose sum is exactly (dx, dy).
                    let at = |s: u32, d: i64| (d * s as i64) / steps as i64;
                    let s = self.step;
                    let ddx = at(s + 1, dx) - at(s, dx);
                    let ddy = at(s + 1, dy) - at(s, dy);
                    self.advance_step(steps);
                    return Tick::Inputs(vec![Input::Drag {
                        button,
                        dx: ddx as f64,
                        dy: ddy as f64,
                    }]);
                }
                Command::Wheel(n) => {
                    self.next();
                    return Tick::Inputs(vec![Input::Wheel {
                        notches: n,
                        at: None,
                    }]);
                }
                Command::Key(k, count) => {
                    self.advance_step(count);
                    return Tick::Inputs(vec![Input::Key(k)]);
                }
                Command::Wait(d) => {
                    let deadline = *self.deadline.get_or_insert(now + d);
                    if now < deadline {
                        return Tick::Wait;
                    }
                    self.next();
                }
                Command::Settle => {
                    if !settled {
                        return Tick::Wait;
                    }
                    self.next();
                }
            }
        }
    }

    fn advance_step(&mut self, steps: u32) {
        self.step += 1;
        if self.step >= steps {
            self.next();
        }
    }

    fn next(&mut self) {
        self.pos += 1;
        self.step = 0;
        self.deadline = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_command() {
        let s = "# view of the head\n\
                 drag left -70 -140 35\n\
                 \n\
                 DRAG right 10 -3   # comment\n\
                 wheel -2.5\n\
                 key Tab\n\
                 key ] 3\n\
                 wait 250\n\
                 settle\n";
        let c = parse(s).unwrap();
        assert_eq!(
            c,
            vec![
                Command::Drag {
                    button: Button::Left,
                    dx: -70,
                    dy: -140,
                    steps: 35
                },
                Command::Drag {
                    button: Button::Right,
                    dx: 10,
                    dy: -3,
                    steps: 3
                },
                Command::Wheel(-2.5),
                Command::Key(ViewKey::NextPreset, 1),
                Command::Key(ViewKey::WindowWider, 3),
                Command::Wait(Duration::from_millis(250)),
                Command::Settle,
            ]
        );
        assert!(parse("").unwrap().is_empty());
    }

    #[test]
    fn reports_errors_with_line_numbers() {
        for (s, line, needle) in [
            ("wait 10\nspin 3", 2, "unknown command 'spin'"),
            ("drag up 1 2", 1, "unknown button"),
            ("drag left 1.5 2", 1, "whole number"),
            ("drag left 1", 1, "usage: drag"),
            ("\n\ndrag left 1 2 0", 3, "STEPS"),
            ("key nope", 1, "unknown key 'nope'"),
            ("key r 0", 1, "COUNT"),
            ("wheel inf", 1, "notches"),
            ("wait -1", 1, "MS"),
            ("settle now", 1, "usage: settle"),
        ] {
            let e = parse(s).unwrap_err();
            assert_eq!(e.line, line, "{s}");
            assert!(e.to_string().contains(needle), "{s}: {e}");
        }
    }

    #[test]
    fn player_spreads_drags_exactly_and_waits() {
        let cmds = parse("drag left 10 -7 4\nkey r 2\nwait 100\nsettle\nwheel 1").unwrap();
        let mut p = Player::new(cmds);
        let t0 = Instant::now();
        let (mut sx, mut sy) = (0.0, 0.0);
        for _ in 0..4 {
            match p.tick(t0, false) {
                Tick::Inputs(v) => match v[0] {
                    Input::Drag { dx, dy, .. } => {
                        assert!(dx.fract() == 0.0 && dy.fract() == 0.0);
                        sx += dx;
                        sy += dy;
                    }
                    ref other => panic!("{other:?}"),
                },
                other => panic!("{other:?}"),
            }
        }
        assert_eq!((sx, sy), (10.0, -7.0));
        let key = Tick::Inputs(vec![Input::Key(ViewKey::ResetView)]);
        assert_eq!(p.tick(t0, false), key);
        assert_eq!(p.tick(t0, false), key);
        assert_eq!(p.tick(t0, false), Tick::Wait);
        assert_eq!(p.tick(t0 + Duration::from_millis(50), false), Tick::Wait);
        // Wait over, but not settled.
        assert_eq!(p.tick(t0 + Duration::from_millis(100), false), Tick::Wait);
        assert_eq!(
            p.tick(t0 + Duration::from_millis(120), true),
            Tick::Inputs(vec![Input::Wheel {
                notches: 1.0,
                at: None
            }])
        );
        assert_eq!(p.tick(t0, true), Tick::Done);
    }
}
