//! The statistics of a run as the JSON of `CLI.md` (`--stats`). Keys named
//! there are an interface; extra keys may be added.

use std::path::Path;

use serde_json::{Map, Value, json};

use crate::error::Result;

/// Writes `value` to `path` atomically (temporary file, then rename).
pub fn write_json(path: &Path, value: &Value) -> Result<()> {
    super::image_io::write_atomically(path, |f| {
        serde_json::to_writer_pretty(&mut *f, value).map_err(|e| e.to_string())?;
        std::io::Write::write_all(f, b"\n").map_err(|e| e.to_string())
    })
}

/// A JSON number, or null when not finite (JSON has no infinity).
pub fn num(x: f64) -> Value {
    if x.is_finite() { json!(x) } else { Value::Null }
}

/// Inserts `(key, value)` pairs into an object.
pub fn extend(obj: &mut Value, pairs: impl IntoIterator<Item = (&'static str, Value)>) {
    if let Value::Object(m) = obj {
        let m: &mut Map<String, Value> = m;
        for (k, v) in pairs {
            m.insert(k.to_string(), v);
        }
    }
}
