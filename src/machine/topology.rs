//! The modelled machine: hypercube dimension, memory per node, link and
//! message costs, node speed. Loaded from `topology/*.ron`; the iPSC/d5 of
//! the paper's section 10 is built in and is the default.

use std::path::Path;

use serde::Deserialize;

use crate::error::fmt_num;
use crate::error::{Error, Result};

/// The built-in default topology (`topology/ipsc-d5.ron`).
pub const IPSC_D5: &str = include_str!("../../topology/ipsc-d5.ron");

/// The largest hypercube dimension accepted (2^10 = 1024 node threads).
pub const MAX_DIMENSION: u32 = 10;

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
struct TopologyFile {
    name: String,
    dimension: u32,
    node_memory: SizeText,
    link_bandwidth_bytes_per_second: f64,
    link_latency_seconds: f64,
    message_overhead_seconds: f64,
    compute_speed: f64,
}

/// A memory size as the file gives it: text with a unit (`"4.5MiB"`), or a
/// plain number of bytes, read as `--node-memory` reads it (`parse_size`).
#[derive(Debug)]
struct SizeText(String);

impl<'de> Deserialize<'de> for SizeText {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = SizeText;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a memory size such as \"4.5MiB\", or a number of bytes")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> std::result::Result<SizeText, E> {
                Ok(SizeText(v.to_string()))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> std::result::Result<SizeText, E> {
                Ok(SizeText(v.to_string()))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> std::result::Result<SizeText, E> {
                Ok(SizeText(v.to_string()))
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> std::result::Result<SizeText, E> {
                Ok(SizeText(v.to_string()))
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// A validated topology.
#[derive(Clone, Debug, PartialEq)]
pub struct Topology {
    pub name: String,
    /// d: the machine has 2^d nodes.
    pub dimension: u32,
    /// Bytes of memory per node.
    pub node_memory: u64,
    /// Bytes per second on one link.
    pub link_bandwidth: f64,
    /// Seconds per hop on a link.
    pub link_latency: f64,
    /// Seconds of software overhead per message sent.
    pub message_overhead: f64,
    /// Node compute speed relative to one host core (0.5: half as fast).
    pub compute_speed: f64,
}

impl Topology {
    pub fn nodes(&self) -> usize {
        1 << self.dimension
    }

    /// The built-in iPSC/d5.
    pub fn ipsc_d5() -> Topology {
        match parse_topology(IPSC_D5, Path::new("<built-in ipsc-d5>")) {
            Ok(t) => t,
            Err(e) => unreachable!("the built-in topology is valid: {e}"),
        }
    }

    /// Reads a topology file: a regular file of at most
    /// `input::MAX_INPUT_BYTES` (`crate::input`).
    pub fn load(path: &Path) -> Result<Topology> {
        let text = crate::input::read_to_string(path)?;
        parse_topology(&text, path)
    }

    /// Applies `--dim` and `--node-memory`.
    pub fn with_overrides(mut self, dim: Option<u32>, memory: Option<u64>) -> Result<Topology> {
        if let Some(d) = dim {
            if d > MAX_DIMENSION {
                return Err(Error::Usage(format!(
                    "--dim must be at most {MAX_DIMENSION}, got {d}"
                )));
            }
            self.dimension = d;
        }
        if let Some(m) = memory {
            self.node_memory = m;
        }
        Ok(self)
    }
}

/// Parses and validates topology text; `file` names it in messages, and
/// its extension picks the syntax, as for scenes: `.json` JSON, else RON.
pub fn parse_topology(text: &str, file: &Path) -> Result<Topology> {
    use crate::scene::SceneSyntax;
    use crate::scene::load::{json_syntax_error, ron_syntax_error};
    // The scenes' rule for `.json`; any other name is RON here.
    let json = matches!(SceneSyntax::from_path(file), Ok(SceneSyntax::Json));
    let t: TopologyFile = if json {
        serde_json::from_str(text).map_err(|e| json_syntax_error(file, &e))?
    } else {
        ron::Options::default()
            .from_str(text)
            .map_err(|e| ron_syntax_error(text, file, &e))?
    };
    let bad = |field: &str, message: String| Error::invalid(file, field, message);
    if t.name.trim().is_empty() {
        return Err(bad(
            "name",
            "name must not be empty: reports name the machine by it".into(),
        ));
    }
    if t.dimension > MAX_DIMENSION {
        return Err(bad(
            "dimension",
            format!(
                "dimension must be at most {MAX_DIMENSION}, got {}",
                t.dimension
            ),
        ));
    }
    let node_memory = parse_size(&t.node_memory.0).map_err(|m| bad("node_memory", m))?;
    // Each value within a range wide enough for any machine worth
    // modelling and narrow enough that the virtual time of any run stays a
    // number: a compute speed of 1e-300 made it 2.5e296 s, a latency of
    // 1.7e308 made it infinite and `scale`'s virtual speedups NaN.
    let within = |field: &str, v: f64, (lo, hi): (f64, f64)| -> Result<f64> {
        if (lo..=hi).contains(&v) {
            Ok(v)
        } else {
            Err(bad(
                field,
                format!(
                    "{field} must be between {} and {}, got {}",
                    fmt_num(lo),
                    fmt_num(hi),
                    fmt_num(v)
                ),
            ))
        }
    };
    Ok(Topology {
        name: t.name,
        dimension: t.dimension,
        node_memory,
        link_bandwidth: within(
            "link_bandwidth_bytes_per_second",
            t.link_bandwidth_bytes_per_second,
            BANDWIDTH_RANGE,
        )?,
        link_latency: within("link_latency_seconds", t.link_latency_seconds, TIME_RANGE)?,
        message_overhead: within(
            "message_overhead_seconds",
            t.message_overhead_seconds,
            TIME_RANGE,
        )?,
        compute_speed: within("compute_speed", t.compute_speed, SPEED_RANGE)?,
    })
}

/// A node's speed relative to one host core (`compute_speed`): from a
/// trillion times slower to a trillion times faster.
const SPEED_RANGE: (f64, f64) = (1e-12, 1e12);
/// A link's bandwidth, bytes per second.
const BANDWIDTH_RANGE: (f64, f64) = (1.0, 1e18);
/// A link's latency and a message's overhead, seconds: up to some eleven
/// days each.
const TIME_RANGE: (f64, f64) = (0.0, 1e6);

/// Parses a memory size: `4.5MiB`, `512KiB`, `2GiB`, `1MB` (= MiB, the
/// paper's megabytes), `1e3KiB`, or plain bytes.
pub fn parse_size(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    // The unit is the letters at the end, so that an exponent's `e` is
    // read as part of the number.
    let split = t.trim_end_matches(|c: char| c.is_ascii_alphabetic()).len();
    let (num, unit) = t.split_at(split);
    let value: f64 = num.trim().parse().map_err(|_| {
        format!("bad memory size {s:?}: expected a number with KiB, MiB, GiB or no unit")
    })?;
    let scale = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "kib" | "kb" | "k" => 1024.0,
        "mib" | "mb" | "m" => 1024.0 * 1024.0,
        "gib" | "gb" | "g" => 1024.0 * 1024.0 * 1024.0,
        other => {
            return Err(format!(
                "bad memory size {s:?}: unknown unit {other:?} (use KiB, MiB or GiB)"
            ));
        }
    };
    let bytes = value * scale;
    if !(1.0..=1e15).contains(&bytes) {
        return Err(format!(
            "bad memory size {s:?}: must be between 1 byte and 1 PB"
        ));
    }
    Ok(bytes.round() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("4.5MiB"), Ok(4_718_592));
        assert_eq!(parse_size("512KiB"), Ok(524_288));
        assert_eq!(parse_size("2GiB"), Ok(2 << 30));
        assert_eq!(parse_size("1000"), Ok(1000));
        assert!(parse_size("-1MiB").is_err());
        assert!(parse_size("4.5 parsecs").is_err());
        assert!(parse_size("").is_err());
        // An exponent is part of the number, not a unit.
        assert_eq!(parse_size("1e3KiB"), Ok(1_024_000));
        let e = parse_size("1e30MiB").unwrap_err();
        assert!(e.contains("between 1 byte and 1 PB"), "{e}");
    }

    #[test]
    fn bundled_topologies_are_valid() {
        for f in ["ipsc-d5", "ipsc-d7", "cluster-d6"] {
            let p = Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("topology")
                .join(format!("{f}.ron"));
            let t = Topology::load(&p).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(t.name, f);
        }
        let d5 = Topology::ipsc_d5();
        assert_eq!((d5.nodes(), d5.node_memory), (32, 4_718_592));
    }

    #[test]
    fn bad_topologies_name_the_place() {
        let refused = |text: &str| {
            parse_topology(text, Path::new("t.ron"))
                .unwrap_err()
                .to_string()
        };
        let ipsc_with = |from: &str, to: &str| {
            let text = IPSC_D5.replace(from, to);
            assert_ne!(text, IPSC_D5, "{from}");
            refused(&text)
        };
        let e = refused("(name: \"x\", dimension: 3)");
        assert!(e.starts_with("t.ron:1:"), "{e}");
        // Said as scene errors are, without the model's type names.
        assert!(
            e.contains("missing field `node_memory` in the topology"),
            "{e}"
        );
        let e = ipsc_with("compute_speed: 0.0000625", "compute_speed: -1.0");
        assert!(e.contains("compute_speed"), "{e}");
        let e = ipsc_with("dimension: 5", "dimension: 40");
        assert!(e.contains("dimension must be at most 10"), "{e}");
        let e = ipsc_with("name: \"ipsc-d5\"", "name: \" \"");
        assert!(e.contains("name must not be empty"), "{e}");
        let e = ipsc_with("node_memory: \"4.5MiB\"", "node_memory: true");
        assert!(e.contains("expected a memory size"), "{e}");
    }

    /// A topology may be JSON (by its extension, as scenes are), and its
    /// memory a plain number of bytes: the same machine either way.
    #[test]
    fn topologies_read_as_json_and_memory_as_bytes() {
        let d5 = Topology::ipsc_d5();
        let bytes = IPSC_D5.replace("node_memory: \"4.5MiB\"", "node_memory: 4718592");
        assert_ne!(bytes, IPSC_D5);
        assert_eq!(parse_topology(&bytes, Path::new("t.ron")).unwrap(), d5);
        let json = format!(
            r#"{{"name": "ipsc-d5", "dimension": 5, "node_memory": "4.5MiB",
                "link_bandwidth_bytes_per_second": {}, "link_latency_seconds": {},
                "message_overhead_seconds": {}, "compute_speed": {}}}"#,
            d5.link_bandwidth, d5.link_latency, d5.message_overhead, d5.compute_speed
        );
        assert_eq!(parse_topology(&json, Path::new("t.json")).unwrap(), d5);
        let e = parse_topology(
            &json.replace("\"dimension\"", "\"dim\""),
            Path::new("t.json"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("t.json:1:") && e.contains("unknown field `dim`"),
            "{e}"
        );
    }

    /// Values that would make the virtual time of a run astronomical,
    /// infinite or NaN are refused with their range.
    #[test]
    fn topology_values_stay_in_ranges_that_keep_virtual_time_a_number() {
        for (from, to, want) in [
            (
                "compute_speed: 0.0000625",
                "compute_speed: 1e-300",
                "compute_speed must be between 1e-12 and 1e12, got 1e-300",
            ),
            (
                "link_latency_seconds: 0.00005",
                "link_latency_seconds: 1.7e308",
                "link_latency_seconds must be between 0 and 1000000, got 1.7e308",
            ),
            (
                "link_bandwidth_bytes_per_second: 1250000.0",
                "link_bandwidth_bytes_per_second: 0.5",
                "link_bandwidth_bytes_per_second must be between 1 and 1e18, got 0.5",
            ),
            (
                "message_overhead_seconds: 0.001",
                "message_overhead_seconds: -0.001",
                "message_overhead_seconds must be between 0 and 1000000, got -0.001",
            ),
        ] {
            let text = IPSC_D5.replace(from, to);
            assert_ne!(text, IPSC_D5, "{from}");
            let e = parse_topology(&text, Path::new("t.ron"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(want), "{e}");
        }
    }
}
