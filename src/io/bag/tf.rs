//! The transform tree of a bag: static edges (`/tf_static`) and moving ones (`/tf`, odometry,
//! stamped poses), each child frame with one parent, looked up at a time stamp by composing the
//! edges from a sensor's frame up to the fixed frame (each moving edge interpolated on its own,
//! as tf2 does).

use crate::io::trajectory::Trajectory;
use nalgebra::Isometry3;
use std::collections::{BTreeMap, HashMap};

/// How a child frame hangs from its parent.
#[derive(Clone)]
enum Edge {
    Static(Isometry3<f64>),
    Moving(Vec<(f64, Isometry3<f64>)>),
    Ready(Trajectory),
}

/// Frames and the transforms between them.
#[derive(Clone, Default)]
pub struct TfTree {
    /// child → (parent, `parent_from_child`).
    edges: BTreeMap<String, (String, Edge)>,
    /// Transforms ignored because their child already had another parent or kind.
    pub conflicts: usize,
}

impl TfTree {
    /// Adds a static `parent_from_child` (a repeat of the same edge is ignored).
    pub fn add_static(&mut self, parent: &str, child: &str, t: Isometry3<f64>) {
        match self.edges.get(child) {
            None => {
                self.edges
                    .insert(child.to_string(), (parent.to_string(), Edge::Static(t)));
            }
            Some((p, Edge::Static(_))) if p == parent => {}
            Some(_) => self.conflicts += 1,
        }
    }

    /// Adds a sample of a moving `parent_from_child` at `t_s`.
    pub fn add_moving(&mut self, parent: &str, child: &str, t_s: f64, t: Isometry3<f64>) {
        let entry = self
            .edges
            .entry(child.to_string())
            .or_insert_with(|| (parent.to_string(), Edge::Moving(Vec::new())));
        match entry {
            (p, Edge::Moving(samples)) if p == parent => samples.push((t_s, t)),
            _ => self.conflicts += 1,
        }
    }

    /// Sorts the moving edges' samples; call once all are added.
    pub fn finish(&mut self) {
        for (_, edge) in self.edges.values_mut() {
            if let Edge::Moving(samples) = edge {
                let trajectory = Trajectory::timed(std::mem::take(samples)).unwrap_or_default();
                *edge = Edge::Ready(trajectory);
            }
        }
    }

    /// The frames from `frame` up to its root, `frame` first.
    pub fn chain(&self, frame: &str) -> Vec<String> {
        let mut out = vec![frame.to_string()];
        while let Some((parent, _)) = self.edges.get(out.last().unwrap()) {
            if out.contains(parent) {
                break; // a cycle: stop rather than loop
            }
            out.push(parent.clone());
        }
        out
    }

    /// Whether an edge of `frame`'s chain moves.
    pub fn moves(&self, frame: &str) -> bool {
        self.chain(frame).iter().any(|f| {
            matches!(
                self.edges.get(f),
                Some((_, Edge::Ready(_) | Edge::Moving(_)))
            )
        })
    }

    /// The child frames with a parent, with the parent and whether the edge moves.
    pub fn edges(&self) -> impl Iterator<Item = (&str, &str, bool)> {
        self.edges
            .iter()
            .map(|(c, (p, e))| (c.as_str(), p.as_str(), !matches!(e, Edge::Static(_))))
    }

    /// `fixed_from_frame` at `t_s`: `Ok(None)` when a moving edge has no pose then (outside
    /// its samples' span); `Err` when `fixed` is not above `frame`.
    pub fn lookup(
        &self,
        fixed: &str,
        frame: &str,
        t_s: f64,
    ) -> std::result::Result<Option<Isometry3<f64>>, String> {
        let mut pose = Isometry3::identity();
        let mut at = frame;
        while at != fixed {
            let Some((parent, edge)) = self.edges.get(at) else {
                return Err(format!(
                    "no transform connects frame '{frame}' to the fixed frame '{fixed}' (its chain: {})",
                    self.chain(frame).join(" → ")
                ));
            };
            let step = match edge {
                Edge::Static(t) => *t,
                Edge::Ready(tr) => match tr.at(t_s) {
                    Some(t) => t,
                    None => return Ok(None),
                },
                Edge::Moving(_) => unreachable!("finish() turns moving edges into trajectories"),
            };
            pose = step * pose;
            at = parent;
            if pose.translation.vector.iter().any(|v| !v.is_finite()) {
                return Err(format!("a non-finite transform above '{at}'"));
            }
        }
        Ok(Some(pose))
    }
}

/// Counts per child frame, for reports.
pub fn describe_edges(tree: &TfTree) -> String {
    let mut by_kind: HashMap<bool, Vec<String>> = HashMap::new();
    for (c, p, moving) in tree.edges() {
        by_kind
            .entry(moving)
            .or_default()
            .push(format!("{p} → {c}"));
    }
    let list = |m| by_kind.get(&m).map_or("none".to_string(), |v| v.join(", "));
    format!("moving: {}; static: {}", list(true), list(false))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn shift(x: f64) -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::identity())
    }

    #[test]
    fn chains_compose_static_and_moving_edges() {
        let mut tf = TfTree::default();
        tf.add_static("base_link", "velodyne", shift(1.0));
        tf.add_moving("map", "base_link", 10.0, shift(0.0));
        tf.add_moving("map", "base_link", 12.0, shift(20.0));
        tf.add_moving("other", "base_link", 11.0, shift(5.0)); // a second parent: ignored
        tf.finish();
        assert_eq!(tf.conflicts, 1);
        assert_eq!(tf.chain("velodyne"), ["velodyne", "base_link", "map"]);
        assert!(tf.moves("velodyne"));
        let p = tf.lookup("map", "velodyne", 11.0).unwrap().unwrap();
        assert!((p.translation.vector - Vector3::new(11.0, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(tf.lookup("map", "velodyne", 9.0), Ok(None));
        let e = tf.lookup("map", "camera", 11.0).unwrap_err();
        assert!(e.contains("'camera'") && e.contains("'map'"), "{e}");
    }
}
