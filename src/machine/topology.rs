//! The modelled machine: hypercube dimension, memory per node, link and
//! message costs, node speed. Loaded from `topology/*.ron`; the iPSC/d5 of
//! the paper's section 10 is built in and is the default.

use std::path::Path;

use serde::Deserialize;

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
    node_memory: String,
    link_bandwidth_bytes_per_second: f64,
    link_latency_seconds: f64,
    message_overhead_seconds: f64,
    compute_speed: f64,
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

/// Parses and validates topology text; `file` names it in messages.
pub fn parse_topology(text: &str, file: &Path) -> Result<Topology> {
    let t: TopologyFile = ron::Options::default()
        .from_str(text)
        .map_err(|e| Error::Syntax {
            file: file.to_path_buf(),
            line: e.span.start.line,
            column: e.span.start.col,
            message: e.code.to_string(),
        })?;
    let bad = |field: &str, message: String| Error::invalid(file, field, message);
    if t.dimension > MAX_DIMENSION {
        return Err(bad(
            "dimension",
            format!(
                "dimension must be at most {MAX_DIMENSION}, got {}",
                t.dimension
            ),
        ));
    }
    let node_memory = parse_size(&t.node_memory).map_err(|m| bad("node_memory", m))?;
    let positive = |field: &str, v: f64| -> Result<f64> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(bad(
                field,
                format!("{field} must be a finite number > 0, got {v}"),
            ))
        }
    };
    let non_negative = |field: &str, v: f64| -> Result<f64> {
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(bad(
                field,
                format!("{field} must be a finite number >= 0, got {v}"),
            ))
        }
    };
    Ok(Topology {
        name: t.name,
        dimension: t.dimension,
        node_memory,
        link_bandwidth: positive(
            "link_bandwidth_bytes_per_second",
            t.link_bandwidth_bytes_per_second,
        )?,
        link_latency: non_negative("link_latency_seconds", t.link_latency_seconds)?,
        message_overhead: non_negative("message_overhead_seconds", t.message_overhead_seconds)?,
        compute_speed: positive("compute_speed", t.compute_speed)?,
    })
}

/// Parses a memory size: `4.5MiB`, `512KiB`, `2GiB`, `1MB` (= MiB, the
/// paper's megabytes), or plain bytes.
pub fn parse_size(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let split = t.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(t.len());
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
        let e = parse_topology("(name: \"x\", dimension: 3)", Path::new("t.ron"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.ron:1:"), "{e}");
        let text = IPSC_D5.replace("compute_speed: 0.0000625", "compute_speed: -1.0");
        let e = parse_topology(&text, Path::new("t.ron"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("compute_speed"), "{e}");
        let text = IPSC_D5.replace("dimension: 5", "dimension: 40");
        assert!(parse_topology(&text, Path::new("t.ron")).is_err());
    }
}
