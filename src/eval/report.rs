//! Evaluation reports: per-surface summaries ([`SurfaceReport`]) gathered with timings, memory
//! figures and parameters into an [`EvaluationReport`], written as JSON (machine-readable, round
//! trips) and Markdown (raw vs. regularized side by side, like the paper's Table I).

use crate::error::{Error, Result};
use crate::eval::stats::ErrorStats;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::Path;

/// Scores of one reconstructed surface (e.g. "raw" or "regularized").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SurfaceReport {
    /// Name of the surface, e.g. "raw", "regularized".
    pub label: String,
    /// Number of mesh vertices.
    pub vertices: u64,
    /// Number of mesh triangles.
    pub triangles: u64,
    /// Total triangle area, m².
    pub surface_area_m2: f64,
    /// Voxels of the grid the surface came from, when known.
    pub voxel_count: Option<u64>,
    /// Bytes stored per voxel in that grid, when known.
    pub bytes_per_voxel: Option<f64>,
    /// Accuracy: distance from each reconstructed point to the nearest ground-truth point, metres.
    pub accuracy: ErrorStats,
    /// Completeness: distance from each selected ground-truth point to the nearest reconstructed
    /// point, metres; `None` when not computed.
    pub completeness: Option<ErrorStats>,
    /// When `accuracy` is restricted to where the LiDAR could have measured
    /// ([`EvaluationReport::coverage`]): the accuracy over every point, for comparison.
    #[serde(default)]
    pub accuracy_unrestricted: Option<ErrorStats>,
}

impl SurfaceReport {
    /// Sets the grid figures (`voxel_count` voxels of `bytes_per_voxel` bytes each).
    pub fn with_voxels(mut self, voxel_count: u64, bytes_per_voxel: f64) -> SurfaceReport {
        self.voxel_count = Some(voxel_count);
        self.bytes_per_voxel = Some(bytes_per_voxel);
        self
    }

    /// Voxel memory `voxel_count · bytes_per_voxel`, bytes, when both are known.
    pub fn voxel_bytes(&self) -> Option<f64> {
        Some(self.voxel_count? as f64 * self.bytes_per_voxel?)
    }
}

/// A whole evaluation: the scene, the ground truth's size, every scored surface, and how long and
/// how much memory the run took.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvaluationReport {
    /// What was reconstructed and from which data, in words (e.g. "KITTI 00 frames 0–100, stereo").
    pub source: String,
    /// Number of ground-truth points.
    pub ground_truth_points: u64,
    /// Scored surfaces; the first is the baseline for relative changes in the Markdown table.
    pub surfaces: Vec<SurfaceReport>,
    /// Wall-clock time per stage, `(stage, seconds)`, in pipeline order.
    pub timings_s: Vec<(String, f64)>,
    /// Memory figures, `(what, bytes)`, e.g. `("peak resident", 1.2e9)`.
    pub memory_bytes: Vec<(String, u64)>,
    /// Free-form run parameters (voxel size, λ, iterations, …).
    pub parameters: serde_json::Value,
    /// When accuracy is scored only where the LiDAR could have measured: its view, as measured
    /// from the scans (`None`: every point is scored).
    #[serde(default)]
    pub coverage: Option<crate::eval::SensorView>,
    /// The `denser` version that wrote the report.
    #[serde(default)]
    pub denser_version: String,
    /// The command line that produced it (so the run can be reproduced).
    #[serde(default)]
    pub command_line: String,
    /// The pictures written beside the report (file names).
    #[serde(default)]
    pub pictures: Vec<String>,
    /// What a reader must know to read the scores right (e.g. that the ground truth is the
    /// LiDAR that was fused), one sentence each.
    #[serde(default)]
    pub notes: Vec<String>,
}

impl EvaluationReport {
    /// An empty report for `source` with `ground_truth_points` ground-truth points.
    pub fn new(source: impl Into<String>, ground_truth_points: u64) -> EvaluationReport {
        EvaluationReport {
            source: source.into(),
            ground_truth_points,
            surfaces: Vec::new(),
            timings_s: Vec::new(),
            memory_bytes: Vec::new(),
            parameters: serde_json::Value::Null,
            coverage: None,
            denser_version: env!("CARGO_PKG_VERSION").to_string(),
            command_line: std::env::args()
                .map(|a| shell_quote(&a))
                .collect::<Vec<_>>()
                .join(" "),
            pictures: Vec::new(),
            notes: Vec::new(),
        }
    }

    /// Writes the report as pretty-printed JSON to `path`.
    pub fn write_json(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let text = serde_json::to_string_pretty(self).map_err(|e| {
            Error::InvalidArgument(format!("cannot encode report for {}: {e}", path.display()))
        })?;
        crate::io::atomic::write_file(path, text.as_bytes())
    }

    /// Reads a report written by [`Self::write_json`].
    pub fn read_json(path: impl AsRef<Path>) -> Result<EvaluationReport> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        serde_json::from_str(&text)
            .map_err(|e| Error::bad_input(path, format!("not an evaluation report: {e}")))
    }

    /// Writes [`Self::to_markdown`] to `path`.
    pub fn write_markdown(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        crate::io::atomic::write_file(path, self.to_markdown().as_bytes())
    }

    /// The report as Markdown: a table with one column per surface and, for every surface after
    /// the first, a column with its relative change from the first (e.g. "−38 %"); then timings,
    /// memory and parameters.
    pub fn to_markdown(&self) -> String {
        let mut md = String::new();
        let _ = writeln!(md, "# Evaluation: {}\n", escape(&self.source));
        let _ = writeln!(
            md,
            "Ground truth: {} points. Accuracy = distance from each reconstructed surface point \
             to the nearest ground-truth point; completeness = distance from each ground-truth \
             point (in the evaluated region) to the nearest reconstructed point.\n",
            self.ground_truth_points
        );
        if let Some(v) = &self.coverage {
            let _ = writeln!(
                md,
                "Accuracy is scored only where the LiDAR could have measured: points within \
                 {:.1} m of some scan and between {:.1}° and {:+.1}° of elevation in its frame (the \
                 range and vertical field of view of the scans' own returns; occlusion is not \
                 modelled). Surfaces above or beyond that have no LiDAR point near them, so their \
                 distance would measure the gap in the ground truth. The unrestricted figures \
                 (every point) are the \"all points\" rows.\n",
                v.range_max_m, v.elevation_min_deg, v.elevation_max_deg
            );
        }
        for n in &self.notes {
            let _ = writeln!(md, "**Note.** {}\n", escape(n));
        }
        if !self.surfaces.is_empty() {
            md.push_str(&self.surface_table());
        }
        if !self.pictures.is_empty() {
            md.push_str("\n## Pictures\n\n");
            for p in &self.pictures {
                let _ = writeln!(md, "![{}]({})\n", escape(p), p);
            }
        }
        if !self.timings_s.is_empty() {
            md.push_str("\n## Timings\n\n| stage | seconds |\n|---|---:|\n");
            for (stage, s) in &self.timings_s {
                let _ = writeln!(md, "| {} | {s:.3} |", escape(stage));
            }
            let total: f64 = self.timings_s.iter().map(|(_, s)| s).sum();
            let _ = writeln!(md, "| **total** | **{total:.3}** |");
        }
        if !self.memory_bytes.is_empty() {
            md.push_str("\n## Memory\n\n| what | MiB |\n|---|---:|\n");
            for (what, bytes) in &self.memory_bytes {
                let _ = writeln!(md, "| {} | {:.1} |", escape(what), *bytes as f64 / MIB);
            }
        }
        if !self.parameters.is_null() {
            let json = serde_json::to_string_pretty(&self.parameters).unwrap_or_default();
            let _ = writeln!(md, "\n## Parameters\n\n```json\n{json}\n```");
        }
        if !self.command_line.is_empty() {
            let _ = writeln!(
                md,
                "\n## Reproduce\n\ndenser {}:\n\n```sh\n{}\n```",
                self.denser_version, self.command_line
            );
        }
        md
    }

    /// The side-by-side surface table.
    fn surface_table(&self) -> String {
        let mut md = String::from("## Surfaces\n\n| metric |");
        let base = &self.surfaces[0];
        for s in &self.surfaces {
            let _ = write!(md, " {} |", escape(&s.label));
        }
        for s in &self.surfaces[1..] {
            let _ = write!(md, " {} vs {} |", escape(&s.label), escape(&base.label));
        }
        md.push_str("\n|---|");
        for _ in 0..(2 * self.surfaces.len() - 1) {
            md.push_str("---:|");
        }
        md.push('\n');
        for row in ROWS {
            let _ = write!(md, "| {} |", row.name);
            for s in &self.surfaces {
                let _ = write!(md, " {} |", fmt_value((row.value)(s), row.decimals));
            }
            for s in &self.surfaces[1..] {
                let _ = write!(md, " {} |", fmt_change((row.value)(base), (row.value)(s)));
            }
            md.push('\n');
        }
        md
    }
}

const MIB: f64 = 1024.0 * 1024.0;

/// `s` as a POSIX shell word (quoted when it holds anything but safe characters).
fn shell_quote(s: &str) -> String {
    let safe = !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,@%+".contains(c));
    if safe {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// One row of the surface table.
struct Row {
    /// Row title with unit.
    name: &'static str,
    /// Decimals shown.
    decimals: usize,
    /// The value, when the surface has it.
    value: fn(&SurfaceReport) -> Option<f64>,
}

const ROWS: &[Row] = &[
    Row {
        name: "scored points",
        decimals: 0,
        value: |s| Some(s.accuracy.count as f64),
    },
    Row {
        name: "accuracy median (m)",
        decimals: 3,
        value: |s| Some(s.accuracy.median_m),
    },
    Row {
        name: "accuracy p75 (m)",
        decimals: 3,
        value: |s| Some(s.accuracy.p75_m),
    },
    Row {
        name: "accuracy p90 (m)",
        decimals: 3,
        value: |s| Some(s.accuracy.p90_m),
    },
    Row {
        name: "accuracy mode (m)",
        decimals: 3,
        value: |s| s.accuracy.mode_m,
    },
    Row {
        name: "accuracy mean (m)",
        decimals: 3,
        value: |s| Some(s.accuracy.mean_m),
    },
    Row {
        name: "accuracy RMSE (m)",
        decimals: 3,
        value: |s| Some(s.accuracy.rmse_m),
    },
    Row {
        name: "accuracy median, all points (m)",
        decimals: 3,
        value: |s| s.accuracy_unrestricted.as_ref().map(|a| a.median_m),
    },
    Row {
        name: "accuracy p75, all points (m)",
        decimals: 3,
        value: |s| s.accuracy_unrestricted.as_ref().map(|a| a.p75_m),
    },
    Row {
        name: "points, all (scored: the first row)",
        decimals: 0,
        value: |s| s.accuracy_unrestricted.as_ref().map(|a| a.count as f64),
    },
    Row {
        name: "completeness median (m)",
        decimals: 3,
        value: |s| s.completeness.as_ref().map(|c| c.median_m),
    },
    Row {
        name: "completeness p75 (m)",
        decimals: 3,
        value: |s| s.completeness.as_ref().map(|c| c.p75_m),
    },
    Row {
        name: "surface area (m²)",
        decimals: 1,
        value: |s| Some(s.surface_area_m2),
    },
    Row {
        name: "vertices",
        decimals: 0,
        value: |s| Some(s.vertices as f64),
    },
    Row {
        name: "triangles",
        decimals: 0,
        value: |s| Some(s.triangles as f64),
    },
    Row {
        name: "voxels",
        decimals: 0,
        value: |s| s.voxel_count.map(|v| v as f64),
    },
    Row {
        name: "bytes/voxel",
        decimals: 1,
        value: |s| s.bytes_per_voxel,
    },
    Row {
        name: "voxel memory (MiB)",
        decimals: 1,
        value: |s| s.voxel_bytes().map(|b| b / MIB),
    },
];

/// A value with `decimals` decimals, or "—" when absent.
fn fmt_value(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.decimals$}"),
        _ => "—".to_string(),
    }
}

/// Relative change from `base` to `v` in whole percent with a true minus sign ("−38 %", "+5 %",
/// "0 %"), or "—" when either is absent or the base is zero.
pub(crate) fn fmt_change(base: Option<f64>, v: Option<f64>) -> String {
    match (base, v) {
        (Some(b), Some(v)) if b != 0.0 && b.is_finite() && v.is_finite() => {
            let pct = ((v - b) / b * 100.0).round();
            if pct < 0.0 {
                format!("\u{2212}{} %", -pct)
            } else if pct > 0.0 {
                format!("+{pct} %")
            } else {
                "0 %".to_string()
            }
        }
        _ => "—".to_string(),
    }
}

/// Escapes the characters that would break a Markdown table cell.
fn escape(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', " ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn change_formatting() {
        assert_eq!(fmt_change(Some(0.1), Some(0.062)), "\u{2212}38 %");
        assert_eq!(fmt_change(Some(100.0), Some(105.0)), "+5 %");
        assert_eq!(fmt_change(Some(1.0), Some(1.001)), "0 %");
        assert_eq!(fmt_change(Some(0.0), Some(1.0)), "—");
        assert_eq!(fmt_change(None, Some(1.0)), "—");
    }
}
