//! The statistics of a run as the JSON of `CLI.md` (`--stats`). Keys named
//! there are an interface; extra keys may be added.

use std::path::Path;

use serde_json::{json, Map, Value};

use crate::error::{Error, Result};

/// Writes `value` to `path` atomically (temporary file, then rename).
pub fn write_json(path: &Path, value: &Value) -> Result<()> {
    let err = |message: String| Error::Write {
        path: path.to_path_buf(),
        message,
    };
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let tmp = tempfile::Builder::new()
        .prefix(".hypercast-")
        .suffix(".tmp")
        .tempfile_in(dir)
        .map_err(|e| err(e.to_string()))?;
    serde_json::to_writer_pretty(tmp.as_file(), value).map_err(|e| err(e.to_string()))?;
    tmp.persist(path).map_err(|e| err(e.error.to_string()))?;
    Ok(())
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
