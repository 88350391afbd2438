//! Parsers for the command-line transfer function, vector and size arguments.
//!
//! - opacity: `"0:0,40:0,80:0.3,255:0.9"` (value:alpha, alpha in 0..1)
//! - colour: `"0:#000000,128:#ff8040,255:#fff"` (value:#rrggbb or value:#rgb)
//! - vector: `"1,-0.5,2"` (finite, non-zero)
//! - size: `"800x600"` (1..=16384 each; `x`, `X` or `×`)
//!
//! Values in the point lists must be finite and strictly increasing. Whitespace around
//! tokens is ignored. Errors name the offending entry, its 1-based position and the
//! problem, e.g. `opacity point 3 ('80:1.7'): alpha 1.7 is outside 0..1`.

use std::fmt;

/// Largest accepted width or height.
pub const MAX_SIZE: usize = 16384;

/// Which kind of argument was being parsed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TfSpecKind {
    Opacity,
    Color,
    Vec3,
    Size,
}

impl TfSpecKind {
    /// Name of one entry, used with a position ("opacity point 3").
    fn item(self) -> &'static str {
        match self {
            TfSpecKind::Opacity => "opacity point",
            TfSpecKind::Color => "colour point",
            TfSpecKind::Vec3 => "vector component",
            TfSpecKind::Size => "size",
        }
    }

    /// Name of the whole argument.
    fn whole(self) -> &'static str {
        match self {
            TfSpecKind::Opacity => "opacity transfer function",
            TfSpecKind::Color => "colour transfer function",
            TfSpecKind::Vec3 => "vector",
            TfSpecKind::Size => "size",
        }
    }

    /// The expected syntax.
    fn form(self) -> &'static str {
        match self {
            TfSpecKind::Opacity => "value:alpha",
            TfSpecKind::Color => "value:#rrggbb or value:#rgb",
            TfSpecKind::Vec3 => "x,y,z",
            TfSpecKind::Size => "WIDTHxHEIGHT",
        }
    }
}

/// What is wrong.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum TfErrorKind {
    /// Nothing (or only whitespace) was given.
    Empty,
    /// An empty entry, e.g. from `"0:0,,1:1"` or a trailing comma.
    EmptyEntry,
    /// The entry does not have the expected shape (missing or extra `:`/`x`).
    Malformed,
    /// `field` (e.g. "value", "alpha", "width") is not a number.
    NotANumber { field: &'static str, text: String },
    /// `field` parsed to infinity or NaN.
    NotFinite { field: &'static str, text: String },
    /// Alpha outside 0..1.
    AlphaOutOfRange(f64),
    /// A colour that is not `#rrggbb`/`#rgb`.
    BadColor(String),
    /// A value not greater than the one before it.
    NotIncreasing { previous: f64, value: f64 },
    /// A vector with other than 3 components.
    WrongComponentCount(usize),
    /// A vector whose components are all zero.
    ZeroVector,
    /// A vector whose length cannot be computed in f64 (overflow or underflow).
    NotNormalizable,
    /// A width or height outside 1..=MAX_SIZE.
    SizeOutOfRange { field: &'static str, text: String },
}

/// A parse error, naming the argument kind, the offending token and its position.
#[derive(Clone, Debug, PartialEq)]
pub struct TfError {
    pub spec: TfSpecKind,
    /// 1-based position of the offending entry, if the error is about one entry.
    pub position: Option<usize>,
    /// The offending entry (trimmed), or the whole argument.
    pub token: String,
    pub kind: TfErrorKind,
}

impl TfError {
    fn at(spec: TfSpecKind, position: usize, token: &str, kind: TfErrorKind) -> TfError {
        TfError {
            spec,
            position: Some(position),
            token: token.to_string(),
            kind,
        }
    }

    fn whole(spec: TfSpecKind, token: &str, kind: TfErrorKind) -> TfError {
        TfError {
            spec,
            position: None,
            token: token.to_string(),
            kind,
        }
    }
}

impl fmt::Display for TfError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.position {
            Some(p) => write!(f, "{} {p} ('{}'): ", self.spec.item(), self.token)?,
            None => write!(f, "{} '{}': ", self.spec.whole(), self.token)?,
        }
        match &self.kind {
            TfErrorKind::Empty => write!(f, "nothing given, expected {}", self.spec.form()),
            TfErrorKind::EmptyEntry => {
                write!(
                    f,
                    "empty entry (stray comma?), expected {}",
                    self.spec.form()
                )
            }
            TfErrorKind::Malformed => write!(f, "expected {}", self.spec.form()),
            TfErrorKind::NotANumber { field, text } => {
                write!(f, "{field} '{text}' is not a number")
            }
            TfErrorKind::NotFinite { field, text } => {
                write!(f, "{field} '{text}' is not a finite number")
            }
            TfErrorKind::AlphaOutOfRange(a) => write!(f, "alpha {a} is outside 0..1"),
            TfErrorKind::BadColor(c) => {
                write!(f, "colour '{c}' is not of the form #rrggbb or #rgb")
            }
            TfErrorKind::NotIncreasing { previous, value } => write!(
                f,
                "value {value} is not greater than the previous value {previous} \
                 (values must be strictly increasing)"
            ),
            TfErrorKind::WrongComponentCount(n) => {
                write!(f, "expected 3 components (x,y,z), found {n}")
            }
            TfErrorKind::ZeroVector => {
                write!(f, "all components are zero; a direction must be non-zero")
            }
            TfErrorKind::NotNormalizable => write!(
                f,
                "components are too large or too small to compute the vector's length"
            ),
            TfErrorKind::SizeOutOfRange { field, text } => {
                write!(f, "{field} {text} is outside 1..={MAX_SIZE}")
            }
        }
    }
}

impl std::error::Error for TfError {}

/// Parses a finite f64, reporting problems against `field`.
fn parse_finite(text: &str, field: &'static str) -> Result<f64, TfErrorKind> {
    let text = text.trim();
    let v: f64 = text.parse().map_err(|_| TfErrorKind::NotANumber {
        field,
        text: text.to_string(),
    })?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(TfErrorKind::NotFinite {
            field,
            text: text.to_string(),
        })
    }
}

/// Splits `"v:rest,v:rest,..."` into trimmed `(position, entry, value, rest)` with
/// finite, strictly increasing values.
fn parse_points(s: &str, spec: TfSpecKind) -> Result<Vec<(usize, String, f64, String)>, TfError> {
    if s.trim().is_empty() {
        return Err(TfError::whole(spec, s.trim(), TfErrorKind::Empty));
    }
    let mut out: Vec<(usize, String, f64, String)> = Vec::new();
    for (i, entry) in s.split(',').enumerate() {
        let pos = i + 1;
        let entry = entry.trim();
        let err = |kind| TfError::at(spec, pos, entry, kind);
        if entry.is_empty() {
            return Err(err(TfErrorKind::EmptyEntry));
        }
        let mut parts = entry.split(':');
        let (Some(value), Some(rest), None) = (parts.next(), parts.next(), parts.next()) else {
            return Err(err(TfErrorKind::Malformed));
        };
        let value = parse_finite(value, "value").map_err(err)?;
        if let Some(&(_, _, previous, _)) = out.last() {
            if value <= previous {
                return Err(err(TfErrorKind::NotIncreasing { previous, value }));
            }
        }
        out.push((pos, entry.to_string(), value, rest.trim().to_string()));
    }
    Ok(out)
}

/// Parses an opacity transfer function `"v:a,v:a,..."`, e.g. `"0:0,40:0,80:0.3,255:0.9"`.
pub fn parse_opacity(s: &str) -> Result<Vec<(f64, f64)>, TfError> {
    let spec = TfSpecKind::Opacity;
    parse_points(s, spec)?
        .into_iter()
        .map(|(pos, entry, value, alpha)| {
            let err = |kind| TfError::at(spec, pos, &entry, kind);
            let a = parse_finite(&alpha, "alpha").map_err(err)?;
            if !(0.0..=1.0).contains(&a) {
                return Err(err(TfErrorKind::AlphaOutOfRange(a)));
            }
            Ok((value, a + 0.0)) // + 0.0 turns -0 into 0
        })
        .collect()
}

/// Parses a colour transfer function `"v:#rrggbb,..."` (or `#rgb`), e.g.
/// `"0:#000000,128:#ff8040,255:#ffffff"`.
pub fn parse_color(s: &str) -> Result<Vec<(f64, [u8; 3])>, TfError> {
    let spec = TfSpecKind::Color;
    parse_points(s, spec)?
        .into_iter()
        .map(|(pos, entry, value, color)| {
            let rgb = parse_hex_color(&color)
                .ok_or_else(|| TfError::at(spec, pos, &entry, TfErrorKind::BadColor(color)))?;
            Ok((value, rgb))
        })
        .collect()
}

/// `#rrggbb` or `#rgb` (hex digits in either case).
pub(crate) fn parse_hex_color(s: &str) -> Option<[u8; 3]> {
    let hex = s.strip_prefix('#')?;
    // Checking every byte first also guarantees ASCII, so slicing below is safe.
    if !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let digit = |b: u8| (b as char).to_digit(16).map(|d| d as u8);
    let b = hex.as_bytes();
    match b.len() {
        6 => {
            let mut rgb = [0u8; 3];
            for (c, pair) in rgb.iter_mut().zip(b.chunks_exact(2)) {
                *c = digit(pair[0])? * 16 + digit(pair[1])?;
            }
            Some(rgb)
        }
        3 => {
            let mut rgb = [0u8; 3];
            for (c, &d) in rgb.iter_mut().zip(b) {
                *c = digit(d)? * 17;
            }
            Some(rgb)
        }
        _ => None,
    }
}

/// Parses `"x,y,z"` (e.g. a light direction): three finite components, not all zero.
pub fn parse_vec3(s: &str) -> Result<[f64; 3], TfError> {
    let spec = TfSpecKind::Vec3;
    let whole = s.trim();
    if whole.is_empty() {
        return Err(TfError::whole(spec, whole, TfErrorKind::Empty));
    }
    let parts: Vec<&str> = whole.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(TfError::whole(
            spec,
            whole,
            TfErrorKind::WrongComponentCount(parts.len()),
        ));
    }
    let mut v = [0f64; 3];
    for (i, (c, part)) in v.iter_mut().zip(&parts).enumerate() {
        let err = |kind| TfError::at(spec, i + 1, part, kind);
        if part.is_empty() {
            return Err(err(TfErrorKind::EmptyEntry));
        }
        *c = parse_finite(part, "component").map_err(err)?;
    }
    if v.iter().all(|c| *c == 0.0) {
        return Err(TfError::whole(spec, whole, TfErrorKind::ZeroVector));
    }
    let len2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    if !(len2.is_finite() && len2 > 0.0) {
        return Err(TfError::whole(spec, whole, TfErrorKind::NotNormalizable));
    }
    Ok(v)
}

/// Parses `"WxH"` (also `X` or `×` as separator), each in 1..=[`MAX_SIZE`].
pub fn parse_size(s: &str) -> Result<(usize, usize), TfError> {
    let spec = TfSpecKind::Size;
    let whole = s.trim();
    let err = |kind| TfError::whole(spec, whole, kind);
    if whole.is_empty() {
        return Err(err(TfErrorKind::Empty));
    }
    let is_sep = |c: char| c == 'x' || c == 'X' || c == '×';
    let mut parts = whole.split(is_sep);
    let (Some(w), Some(h), None) = (parts.next(), parts.next(), parts.next()) else {
        return Err(err(TfErrorKind::Malformed));
    };
    let dim = |text: &str, field: &'static str| -> Result<usize, TfError> {
        let text = text.trim();
        if text.is_empty() {
            return Err(err(TfErrorKind::Malformed));
        }
        let digits = text.strip_prefix('+').unwrap_or(text);
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return Err(err(TfErrorKind::NotANumber {
                field,
                text: text.to_string(),
            }));
        }
        match digits.parse::<usize>() {
            Ok(n) if (1..=MAX_SIZE).contains(&n) => Ok(n),
            _ => Err(err(TfErrorKind::SizeOutOfRange {
                field,
                text: text.to_string(),
            })),
        }
    };
    Ok((dim(w, "width")?, dim(h, "height")?))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kind<T: fmt::Debug>(r: Result<T, TfError>) -> (TfErrorKind, Option<usize>, String) {
        let e = r.expect_err("expected an error");
        let msg = e.to_string();
        (e.kind, e.position, msg)
    }

    // ---------------------------------------------------------------- opacity

    #[test]
    fn opacity_valid() {
        assert_eq!(
            parse_opacity("0:0,40:0,80:0.3,255:0.9").unwrap(),
            vec![(0.0, 0.0), (40.0, 0.0), (80.0, 0.3), (255.0, 0.9)]
        );
        assert_eq!(
            parse_opacity("  -10.5 : 1 ,\t1e3:0.25 ").unwrap(),
            vec![(-10.5, 1.0), (1000.0, 0.25)]
        );
        assert_eq!(parse_opacity("7:.5").unwrap(), vec![(7.0, 0.5)]);
        assert_eq!(parse_opacity("0:1").unwrap(), vec![(0.0, 1.0)]);
    }

    #[test]
    fn opacity_alpha_out_of_range_message() {
        let e = parse_opacity("0:0,40:0,80:1.7,255:0.9").unwrap_err();
        assert_eq!(
            e.to_string(),
            "opacity point 3 ('80:1.7'): alpha 1.7 is outside 0..1"
        );
        assert_eq!(e.position, Some(3));
        assert_eq!(e.token, "80:1.7");
        let (k, p, _) = kind(parse_opacity("0:-0.1"));
        assert_eq!((k, p), (TfErrorKind::AlphaOutOfRange(-0.1), Some(1)));
    }

    #[test]
    fn opacity_invalid() {
        let (k, p, m) = kind(parse_opacity(""));
        assert_eq!((k, p), (TfErrorKind::Empty, None));
        assert!(m.contains("value:alpha"), "{m}");
        assert_eq!(kind(parse_opacity("   ")).0, TfErrorKind::Empty);

        let (k, p, m) = kind(parse_opacity("0:0,,255:1"));
        assert_eq!((k, p), (TfErrorKind::EmptyEntry, Some(2)));
        assert!(m.starts_with("opacity point 2"), "{m}");
        assert_eq!(kind(parse_opacity("0:0,")).1, Some(2));

        let (k, p, m) = kind(parse_opacity("0:0,128"));
        assert_eq!((k, p), (TfErrorKind::Malformed, Some(2)));
        assert!(m.contains("('128')") && m.contains("value:alpha"), "{m}");
        assert_eq!(kind(parse_opacity("0:0:1")).0, TfErrorKind::Malformed);

        let (k, p, m) = kind(parse_opacity("0:0,abc:1"));
        assert_eq!(
            (k, p),
            (
                TfErrorKind::NotANumber {
                    field: "value",
                    text: "abc".into()
                },
                Some(2)
            )
        );
        assert!(m.contains("value 'abc' is not a number"), "{m}");
        let (k, _, m) = kind(parse_opacity("0:x"));
        assert!(
            matches!(k, TfErrorKind::NotANumber { field: "alpha", .. }),
            "{m}"
        );
        assert!(matches!(
            kind(parse_opacity("0:")).0,
            TfErrorKind::NotANumber { .. }
        ));
        assert!(matches!(
            kind(parse_opacity(":0.5")).0,
            TfErrorKind::NotANumber { .. }
        ));

        for s in ["inf:0", "0:0,NaN:1", "-infinity:0"] {
            assert!(
                matches!(
                    kind(parse_opacity(s)).0,
                    TfErrorKind::NotFinite { field: "value", .. }
                ),
                "{s}"
            );
        }
        assert!(matches!(
            kind(parse_opacity("0:nan")).0,
            TfErrorKind::NotFinite { field: "alpha", .. }
        ));

        let (k, p, m) = kind(parse_opacity("0:0,80:0.5,40:1"));
        assert_eq!(
            (k, p),
            (
                TfErrorKind::NotIncreasing {
                    previous: 80.0,
                    value: 40.0
                },
                Some(3)
            )
        );
        assert!(
            m.contains("strictly increasing") && m.contains("('40:1')"),
            "{m}"
        );
        assert!(matches!(
            kind(parse_opacity("5:0,5:1")).0,
            TfErrorKind::NotIncreasing { .. }
        ));
    }

    // ---------------------------------------------------------------- colour

    #[test]
    fn color_valid() {
        assert_eq!(
            parse_color("0:#000000,128:#ff8040,255:#ffffff").unwrap(),
            vec![
                (0.0, [0, 0, 0]),
                (128.0, [255, 128, 64]),
                (255.0, [255, 255, 255])
            ]
        );
        assert_eq!(
            parse_color(" 0 : #F80 , 1.5:#aBcDeF").unwrap(),
            vec![(0.0, [255, 136, 0]), (1.5, [0xab, 0xcd, 0xef])]
        );
    }

    #[test]
    fn color_invalid() {
        for bad in [
            "ff8040", "#ff804", "#ff80400", "#gg0000", "#", "", "#+f+f+f", "#ééé", "#1234",
        ] {
            let s = format!("0:#000,10:{bad}");
            let e = parse_color(&s).unwrap_err();
            assert_eq!(e.kind, TfErrorKind::BadColor(bad.to_string()), "{s}");
            assert_eq!(e.position, Some(2));
            assert!(e.to_string().starts_with("colour point 2 ("), "{e}");
        }
        assert_eq!(kind(parse_color("")).0, TfErrorKind::Empty);
        assert_eq!(
            kind(parse_color("0:#000,,1:#fff")).0,
            TfErrorKind::EmptyEntry
        );
        assert_eq!(kind(parse_color("#ffffff")).0, TfErrorKind::Malformed);
        assert!(matches!(
            kind(parse_color("a:#fff")).0,
            TfErrorKind::NotANumber { .. }
        ));
        assert!(matches!(
            kind(parse_color("inf:#fff")).0,
            TfErrorKind::NotFinite { .. }
        ));
        let e = parse_color("0:#000,255:#fff,128:#888").unwrap_err();
        assert_eq!(e.position, Some(3));
        assert!(matches!(e.kind, TfErrorKind::NotIncreasing { .. }));
    }

    // ---------------------------------------------------------------- vec3

    #[test]
    fn vec3_valid() {
        assert_eq!(parse_vec3("1,2,3").unwrap(), [1.0, 2.0, 3.0]);
        assert_eq!(parse_vec3(" -0.5 , 0 ,1e-3 ").unwrap(), [-0.5, 0.0, 0.001]);
        assert_eq!(parse_vec3("0,0,-1").unwrap(), [0.0, 0.0, -1.0]);
    }

    #[test]
    fn vec3_invalid() {
        assert_eq!(kind(parse_vec3("")).0, TfErrorKind::Empty);
        assert_eq!(
            kind(parse_vec3("1,2")).0,
            TfErrorKind::WrongComponentCount(2)
        );
        assert_eq!(
            kind(parse_vec3("1,2,3,4")).0,
            TfErrorKind::WrongComponentCount(4)
        );
        let (k, p, m) = kind(parse_vec3("1,,3"));
        assert_eq!((k, p), (TfErrorKind::EmptyEntry, Some(2)));
        assert!(m.starts_with("vector component 2"), "{m}");
        let (k, p, m) = kind(parse_vec3("1,y,3"));
        assert_eq!(
            (k, p),
            (
                TfErrorKind::NotANumber {
                    field: "component",
                    text: "y".into()
                },
                Some(2)
            )
        );
        assert!(m.contains("('y')"), "{m}");
        assert!(matches!(
            kind(parse_vec3("1,2,inf")).0,
            TfErrorKind::NotFinite { .. }
        ));
        assert!(matches!(
            kind(parse_vec3("NaN,2,3")).0,
            TfErrorKind::NotFinite { .. }
        ));
        let (k, _, m) = kind(parse_vec3("0, 0.0, -0"));
        assert_eq!(k, TfErrorKind::ZeroVector);
        assert!(m.contains("non-zero"), "{m}");
        assert_eq!(
            kind(parse_vec3("1e300,0,0")).0,
            TfErrorKind::NotNormalizable
        );
        assert_eq!(
            kind(parse_vec3("1e-300,0,0")).0,
            TfErrorKind::NotNormalizable
        );
    }

    // ---------------------------------------------------------------- size

    #[test]
    fn size_valid() {
        assert_eq!(parse_size("800x600").unwrap(), (800, 600));
        assert_eq!(parse_size(" 1 X 16384 ").unwrap(), (1, 16384));
        assert_eq!(parse_size("64×32").unwrap(), (64, 32));
    }

    #[test]
    fn size_invalid() {
        assert_eq!(kind(parse_size("")).0, TfErrorKind::Empty);
        for s in ["800", "800x", "x600", "1x2x3", "800*600"] {
            assert_eq!(kind(parse_size(s)).0, TfErrorKind::Malformed, "{s}");
        }
        let (k, _, m) = kind(parse_size("0x10"));
        assert_eq!(
            k,
            TfErrorKind::SizeOutOfRange {
                field: "width",
                text: "0".into()
            }
        );
        assert_eq!(m, "size '0x10': width 0 is outside 1..=16384");
        assert!(matches!(
            kind(parse_size("10x16385")).0,
            TfErrorKind::SizeOutOfRange {
                field: "height",
                ..
            }
        ));
        assert!(matches!(
            kind(parse_size("99999999999999999999999x1")).0,
            TfErrorKind::SizeOutOfRange { field: "width", .. }
        ));
        for s in ["-5x10", "1.5x10", "ax10", "10x+", "10x1e3"] {
            assert!(
                matches!(kind(parse_size(s)).0, TfErrorKind::NotANumber { .. }),
                "{s}"
            );
        }
    }
}
