//! Transfer-function files (`--tf FILE`, the viewer's `T` key) and their resolution to
//! the stored values a volume is classified over.
//!
//! # Schema (version 1)
//!
//! ```json
//! {
//!   "version": 1,
//!   "units": "raw",
//!   "mode": "composite",
//!   "shading": true,
//!   "opacity": [[0, 0], [60, 0], [120, 0.4], [255, 0.9]],
//!   "color": [[0, "#805040"], [255, "#fffff0"]],
//!   "gradient_opacity": [[0, 0.2], [40, 1]]
//! }
//! ```
//!
//! - `version` (required): 1.
//! - `units` (default `"raw"`): what the values of `opacity` and `color` (and the
//!   magnitudes of `gradient_opacity`) are in: `"raw"` stored voxel values (as on the
//!   command line); `"hu"` Hounsfield units, mapped through the volume's value mapping
//!   (DICOM RescaleSlope/Intercept, NIfTI `scl_slope`/`scl_inter`, a sidecar's
//!   `mapping`); the volume must have one, else the file is refused; `"normalized"` 0..1
//!   over the volume's normalised range ([`crate::presets::data_range`]).
//! - `mode` (default `"composite"`): or `"mip"`.
//! - `shading` (optional): turns shading on (`true`) or leaves it to the command line.
//! - `opacity` (required): `[value, alpha]` pairs, values strictly increasing, alpha in
//!   0..1 (per unit of the smallest voxel spacing).
//! - `color` (optional; default the CLI's warm ramp): `[value, "#rrggbb"]` pairs.
//! - `gradient_opacity` (optional): `[magnitude, factor]` pairs (factor in 0..1).
//!
//! Unknown fields are refused (they are usually typos). Errors name the file and the
//! field, e.g. `tf.json: "opacity"[2]: alpha 1.5 is outside 0..1`.

use serde_json::{json, Map, Value};
use std::fmt;
use std::path::{Path, PathBuf};

/// Largest accepted transfer-function file.
const MAX_BYTES: u64 = 1 << 20;
/// Largest number of points in one list.
const MAX_POINTS: usize = 4096;

/// Units of the values in a transfer function.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Units {
    /// Stored voxel values.
    Raw,
    /// Hounsfield units.
    Hu,
    /// 0..1 over the normalised data range.
    Normalized,
}

impl Units {
    /// The schema's name.
    pub fn as_str(self) -> &'static str {
        match self {
            Units::Raw => "raw",
            Units::Hu => "hu",
            Units::Normalized => "normalized",
        }
    }
}

/// A transfer function as a file or a preset gives it.
#[derive(Clone, Debug, PartialEq)]
pub struct TfSpec {
    pub units: Units,
    /// Maximum intensity projection instead of compositing.
    pub mip: bool,
    /// `Some(true)` turns shading on.
    pub shading: Option<bool>,
    pub opacity: Vec<(f64, f64)>,
    pub color: Option<Vec<(f64, [u8; 3])>>,
    pub gradient_opacity: Option<Vec<(f64, f64)>>,
}

/// A transfer function in stored values, ready to classify with.
#[derive(Clone, Debug, PartialEq)]
pub struct Resolved {
    pub mip: bool,
    pub shading: Option<bool>,
    pub opacity: Vec<(f64, f64)>,
    pub color: Option<Vec<(f64, [u8; 3])>>,
    pub gradient_opacity: Option<Vec<(f64, f64)>>,
}

/// What a transfer function's units are resolved against.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValueScale {
    /// Normalised range: `Units::Normalized` 0..1 spans it.
    pub range: (u16, u16),
    /// `(slope, intercept)` with HU = stored · slope + intercept, when known.
    pub hu: Option<(f64, f64)>,
}

/// A bad transfer-function file or preset request: names the file (the TF file, or the
/// volume a preset does not fit) and, when there is one, the field.
#[derive(Clone, Debug, PartialEq)]
pub struct TfFileError {
    pub path: PathBuf,
    pub field: Option<String>,
    pub reason: String,
}

impl fmt::Display for TfFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.field {
            Some(field) => write!(f, "{}: {field}: {}", self.path.display(), self.reason),
            None => write!(f, "{}: {}", self.path.display(), self.reason),
        }
    }
}

impl std::error::Error for TfFileError {}

impl TfSpec {
    /// Converts to stored values. `what` names the source in errors (the volume, for a
    /// preset; the TF file otherwise).
    pub fn resolve(&self, scale: &ValueScale, what: &Path) -> Result<Resolved, TfFileError> {
        let (lo, hi) = (scale.range.0 as f64, scale.range.1 as f64);
        let span = (hi - lo).max(1.0);
        let (slope, intercept) = match (self.units, scale.hu) {
            (Units::Hu, None) => {
                return Err(TfFileError {
                    path: what.to_path_buf(),
                    field: None,
                    reason: "the transfer function is in Hounsfield units, but the volume has \
                             no HU mapping (no CT modality, no HU rescale, values do not look \
                             like HU); use raw or normalized units"
                        .into(),
                })
            }
            (_, hu) => hu.unwrap_or((1.0, 0.0)),
        };
        // Linear maps to stored values (and of gradient magnitudes).
        let value = |v: f64| match self.units {
            Units::Raw => v,
            Units::Normalized => lo + v * span,
            Units::Hu => (v - intercept) / slope,
        };
        let magnitude = |m: f64| match self.units {
            Units::Raw => m,
            Units::Normalized => m * span,
            Units::Hu => m / slope,
        };
        Ok(Resolved {
            mip: self.mip,
            shading: self.shading,
            opacity: self.opacity.iter().map(|&(v, a)| (value(v), a)).collect(),
            color: self
                .color
                .as_ref()
                .map(|c| c.iter().map(|&(v, rgb)| (value(v), rgb)).collect()),
            gradient_opacity: self
                .gradient_opacity
                .as_ref()
                .map(|g| g.iter().map(|&(m, f)| (magnitude(m), f)).collect()),
        })
    }

    /// The schema's JSON.
    pub fn to_json(&self) -> Value {
        let pairs = |p: &[(f64, f64)]| p.iter().map(|&(v, a)| json!([v, a])).collect::<Vec<_>>();
        let mut m = Map::new();
        m.insert("version".into(), json!(1));
        m.insert("units".into(), json!(self.units.as_str()));
        m.insert(
            "mode".into(),
            json!(if self.mip { "mip" } else { "composite" }),
        );
        if let Some(s) = self.shading {
            m.insert("shading".into(), json!(s));
        }
        m.insert("opacity".into(), json!(pairs(&self.opacity)));
        if let Some(c) = &self.color {
            let c: Vec<Value> = c
                .iter()
                .map(|&(v, [r, g, b])| json!([v, format!("#{r:02x}{g:02x}{b:02x}")]))
                .collect();
            m.insert("color".into(), json!(c));
        }
        if let Some(g) = &self.gradient_opacity {
            m.insert("gradient_opacity".into(), json!(pairs(g)));
        }
        Value::Object(m)
    }

    /// The schema's JSON as text: one field per line, in schema order, each list on
    /// one line.
    pub fn to_text(&self) -> String {
        let v = self.to_json();
        let order = [
            "version",
            "units",
            "mode",
            "shading",
            "opacity",
            "color",
            "gradient_opacity",
        ];
        let fields: Vec<String> = order
            .iter()
            .filter_map(|k| Some(format!("  \"{k}\": {}", v.get(*k)?)))
            .collect();
        format!("{{\n{}\n}}\n", fields.join(",\n"))
    }

    /// Writes [`TfSpec::to_text`] to `path`.
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        std::fs::write(path, self.to_text())
    }

    /// Reads a transfer-function file.
    pub fn load(path: &Path) -> Result<TfSpec, TfFileError> {
        let err = |reason: String| TfFileError {
            path: path.to_path_buf(),
            field: None,
            reason,
        };
        let len = std::fs::metadata(path)
            .map_err(|e| err(format!("cannot read: {e}")))?
            .len();
        if len > MAX_BYTES {
            return Err(err(format!(
                "{len} bytes is too large for a transfer-function file"
            )));
        }
        let text = std::fs::read(path).map_err(|e| err(format!("cannot read: {e}")))?;
        let v: Value =
            serde_json::from_slice(&text).map_err(|e| err(format!("invalid JSON: {e}")))?;
        TfSpec::from_json(&v, path)
    }

    /// Parses the schema; `path` names the file in errors.
    pub fn from_json(v: &Value, path: &Path) -> Result<TfSpec, TfFileError> {
        // `field` is a field name, or a name with an index (`opacity[2]`).
        let field_err = |field: &str, reason: String| {
            let label = match field.split_once('[') {
                Some((name, index)) => format!("\"{name}\"[{index}"),
                None => format!("\"{field}\""),
            };
            TfFileError {
                path: path.to_path_buf(),
                field: Some(label),
                reason,
            }
        };
        let Value::Object(m) = v else {
            return Err(TfFileError {
                path: path.to_path_buf(),
                field: None,
                reason: "expected a JSON object".into(),
            });
        };
        const KNOWN: [&str; 7] = [
            "version",
            "units",
            "mode",
            "shading",
            "opacity",
            "color",
            "gradient_opacity",
        ];
        if let Some(k) = m.keys().find(|k| !KNOWN.contains(&k.as_str())) {
            return Err(field_err(
                k,
                format!("unknown field (known: {})", KNOWN.join(", ")),
            ));
        }
        match m.get("version") {
            None => return Err(field_err("version", "missing (expected 1)".into())),
            Some(v) if v.as_u64() == Some(1) => {}
            Some(v) => {
                return Err(field_err(
                    "version",
                    format!("unsupported version {v} (this program reads version 1)"),
                ))
            }
        }
        let units = match m.get("units").map(|u| u.as_str()) {
            None | Some(Some("raw")) => Units::Raw,
            Some(Some("hu")) => Units::Hu,
            Some(Some("normalized")) => Units::Normalized,
            Some(_) => {
                return Err(field_err(
                    "units",
                    "expected \"raw\", \"hu\" or \"normalized\"".into(),
                ))
            }
        };
        let mip = match m.get("mode").map(|u| u.as_str()) {
            None | Some(Some("composite")) => false,
            Some(Some("mip")) => true,
            Some(_) => {
                return Err(field_err(
                    "mode",
                    "expected \"composite\" or \"mip\"".into(),
                ))
            }
        };
        let shading = match m.get("shading") {
            None => None,
            Some(Value::Bool(b)) => Some(*b),
            Some(_) => return Err(field_err("shading", "expected true or false".into())),
        };
        let opacity = match m.get("opacity") {
            None => return Err(field_err("opacity", "missing".into())),
            Some(v) => number_pairs(v, "opacity", &field_err)?,
        };
        let gradient_opacity = m
            .get("gradient_opacity")
            .map(|v| number_pairs(v, "gradient_opacity", &field_err))
            .transpose()?;
        let color = m
            .get("color")
            .map(|v| color_pairs(v, &field_err))
            .transpose()?;
        Ok(TfSpec {
            units,
            mip,
            shading,
            opacity,
            color,
            gradient_opacity,
        })
    }
}

type FieldErr<'a> = &'a dyn Fn(&str, String) -> TfFileError;

/// The array of `[value, x]` pairs of `field`, values finite and strictly increasing.
fn pairs<'v>(
    v: &'v Value,
    field: &str,
    err: FieldErr<'_>,
) -> Result<Vec<(f64, &'v Value)>, TfFileError> {
    let Value::Array(items) = v else {
        return Err(err(field, "expected an array of [value, ...] pairs".into()));
    };
    if items.is_empty() {
        return Err(err(field, "needs at least one point".into()));
    }
    if items.len() > MAX_POINTS {
        return Err(err(field, format!("more than {MAX_POINTS} points")));
    }
    let mut out: Vec<(f64, &Value)> = Vec::with_capacity(items.len());
    for (i, item) in items.iter().enumerate() {
        let at = |reason: String| err(&format!("{field}[{i}]"), reason);
        let (Some(x), Some(y), None) = (
            item.get(0).and_then(Value::as_f64),
            item.get(1),
            item.get(2),
        ) else {
            return Err(at(
                "expected a [value, ...] pair with a numeric value".into()
            ));
        };
        if !x.is_finite() {
            return Err(at(format!("value {x} is not finite")));
        }
        if let Some(&(prev, _)) = out.last() {
            if x <= prev {
                return Err(at(format!(
                    "value {x} is not greater than the previous value {prev} (values must be \
                     strictly increasing)"
                )));
            }
        }
        out.push((x, y));
    }
    Ok(out)
}

fn number_pairs(v: &Value, field: &str, err: FieldErr<'_>) -> Result<Vec<(f64, f64)>, TfFileError> {
    pairs(v, field, err)?
        .into_iter()
        .enumerate()
        .map(|(i, (x, y))| {
            let a = y
                .as_f64()
                .filter(|a| (0.0..=1.0).contains(a))
                .ok_or_else(|| {
                    err(
                        &format!("{field}[{i}]"),
                        format!("{y} is not a number in 0..1"),
                    )
                })?;
            Ok((x, a + 0.0))
        })
        .collect()
}

fn color_pairs(v: &Value, err: FieldErr<'_>) -> Result<Vec<(f64, [u8; 3])>, TfFileError> {
    pairs(v, "color", err)?
        .into_iter()
        .enumerate()
        .map(|(i, (x, y))| {
            let rgb = y
                .as_str()
                .and_then(crate::tfspec::parse_hex_color)
                .ok_or_else(|| {
                    err(
                        &format!("color[{i}]"),
                        format!("{y} is not a colour \"#rrggbb\" or \"#rgb\""),
                    )
                })?;
            Ok((x, rgb))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn save_and_load_round_trip_exactly() {
        let spec = TfSpec {
            units: Units::Normalized,
            mip: true,
            shading: Some(false),
            opacity: vec![
                (0.1 * 3.0, 0.0),
                (109.65, 0.1 + 0.2),
                (145.35000000000002, 1.0),
            ],
            color: Some(vec![(0.0, [1, 2, 3]), (1.0 / 3.0, [0xff, 0x80, 0])]),
            gradient_opacity: Some(vec![(0.0, 0.5), (7.25, 1.0)]),
        };
        let p = std::env::temp_dir().join(format!("swtf-{}.json", std::process::id()));
        spec.save(&p).unwrap();
        assert_eq!(TfSpec::load(&p).unwrap(), spec);
        std::fs::remove_file(&p).unwrap();
        let text = spec.to_text();
        assert!(
            text.starts_with("{\n  \"version\": 1,\n  \"units\": \"normalized\""),
            "{text}"
        );
    }

    #[test]
    fn errors_name_the_field() {
        let p = Path::new("t.json");
        let e = |s: &str| {
            TfSpec::from_json(&serde_json::from_str(s).unwrap(), p)
                .unwrap_err()
                .to_string()
        };
        assert_eq!(e("[]"), "t.json: expected a JSON object");
        assert_eq!(
            e(r#"{"version": 1, "opacity": [[0, 0]], "units": "mm"}"#),
            "t.json: \"units\": expected \"raw\", \"hu\" or \"normalized\""
        );
        assert!(e(r#"{"version": 1, "opacity": []}"#).contains("\"opacity\": needs at least one"));
        assert!(e(r#"{"version": 1, "opacity": [[0, 0, 1]]}"#).contains("\"opacity\"[0]: expected"));
        assert!(
            e(r#"{"version": 1, "opacity": [[0, 0]], "gradient_opacity": [[1, -1]]}"#)
                .contains("\"gradient_opacity\"[0]: -1 is not a number in 0..1")
        );
        assert!(e(r#"{"version": 1, "opacity": [[0, 0]], "shading": 1}"#).contains("\"shading\""));
    }

    /// Mangled files give errors or specs, never panics.
    #[test]
    fn mangled_files_never_panic() {
        let good = br##"{"version": 1, "units": "hu", "mode": "mip", "shading": true, "opacity": [[0, 0], [1.5, 1]], "color": [[0, "#fff"], [2, "#102030"]], "gradient_opacity": [[0, 0.5]]}"##;
        let alphabet = b"{}[]\":,-0123456789.eE#abfhumnrtv \\\x00\xff";
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let scale = ValueScale {
            range: (0, 10),
            hu: Some((1e-300, 0.0)),
        };
        for _ in 0..2000 {
            let mut b = good.to_vec();
            for _ in 0..(next() % 4 + 1) {
                let i = (next() as usize) % b.len();
                b[i] = alphabet[(next() as usize) % alphabet.len()];
            }
            let Ok(v) = serde_json::from_slice::<Value>(&b) else {
                continue;
            };
            if let Ok(spec) = TfSpec::from_json(&v, Path::new("m.json")) {
                let _ = spec.resolve(&scale, Path::new("v"));
                let _ = spec.to_text();
            }
        }
    }

    #[test]
    fn units_resolve_linearly() {
        let spec = TfSpec {
            units: Units::Hu,
            mip: false,
            shading: None,
            opacity: vec![(-1000.0, 0.0), (1000.0, 1.0)],
            color: None,
            gradient_opacity: Some(vec![(100.0, 1.0)]),
        };
        let scale = ValueScale {
            range: (0, 255),
            hu: Some((12.0, -1018.5)),
        };
        let r = spec.resolve(&scale, Path::new("v")).unwrap();
        assert_eq!(r.opacity, vec![(18.5 / 12.0, 0.0), (2018.5 / 12.0, 1.0)]);
        let mut no_hu = spec.clone();
        no_hu.units = Units::Normalized;
        let r2 = no_hu
            .resolve(
                &ValueScale {
                    range: (10, 20),
                    hu: None,
                },
                Path::new("v"),
            )
            .unwrap();
        assert_eq!(r2.opacity, vec![(-9990.0, 0.0), (10010.0, 1.0)]);
        assert_eq!(r.gradient_opacity, Some(vec![(100.0 / 12.0, 1.0)]));
    }
}
