use super::*;

fn ray(o: [f64; 3], d: [f64; 3]) -> Ray {
    Ray::new(Point3::from(o), Vector3::from(d))
}

#[test]
fn triangle_hit_matches_plane_equation() {
    let s = Shape::triangle(
        Vector3::new(0.0, 0.0, 5.0),
        Vector3::new(4.0, 0.0, 5.0),
        Vector3::new(0.0, 4.0, 5.0),
    );
    let (t, n) = s
        .intersect(&ray([1.0, 1.0, 0.0], [0.0, 0.0, 2.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - 2.5).abs() < 1e-12);
    assert!((n - Vector3::new(0.0, 0.0, 1.0)).norm() < 1e-12);
    assert!(s
        .intersect(&ray([3.0, 3.0, 0.0], [0.0, 0.0, 1.0]), 0.0, 100.0)
        .is_none());
    assert!(s
        .intersect(&ray([1.0, 1.0, 0.0], [0.0, 0.0, 1.0]), 0.0, 4.0)
        .is_none());
}

#[test]
fn rotated_box_hit_matches_analytic_distance() {
    // A 2×2×2 cube at (0,0,10) turned by 45°: its nearest corner edge is at z = 10 − √2.
    let a = std::f64::consts::FRAC_1_SQRT_2;
    let s = Shape::Box {
        center: Vector3::new(0.0, 0.0, 10.0),
        half_m: Vector3::new(1.0, 1.0, 1.0),
        axis: [a, a],
    };
    let (t, _) = s
        .intersect(&ray([0.0, 0.5, 0.0], [0.0, 0.0, 1.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - (10.0 - 2f64.sqrt())).abs() < 1e-12, "t = {t}");
    // Axis-aligned: hit the face x = −1 from the left with normal −x.
    let s = Shape::aabox(Vector3::new(-1.0, -1.0, 9.0), Vector3::new(1.0, 1.0, 11.0));
    let (t, n) = s
        .intersect(&ray([-5.0, 0.0, 10.0], [2.0, 0.0, 0.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - 2.0).abs() < 1e-12);
    assert!((n + Vector3::x()).norm() < 1e-12);
    // From inside: the exit.
    let (t, n) = s
        .intersect(&ray([0.0, 0.0, 10.0], [0.0, 1.0, 0.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - 1.0).abs() < 1e-12 && (n - Vector3::y()).norm() < 1e-12);
}

#[test]
fn sphere_and_ellipsoid_hits() {
    let s = Shape::Ellipsoid {
        center: Vector3::new(0.0, 0.0, 10.0),
        radii_m: Vector3::new(2.0, 2.0, 2.0),
    };
    let (t, n) = s
        .intersect(&ray([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - 8.0).abs() < 1e-12 && (n + Vector3::z()).norm() < 1e-12);
    // Off-centre: sphere |p − c| = 2 at height 1 → z = 10 − √3.
    let (t, _) = s
        .intersect(&ray([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - (10.0 - 3f64.sqrt())).abs() < 1e-12);
    let e = Shape::Ellipsoid {
        center: Vector3::new(0.0, 0.0, 10.0),
        radii_m: Vector3::new(1.0, 2.0, 3.0),
    };
    let (t, _) = e
        .intersect(&ray([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - 7.0).abs() < 1e-12);
    let (t, _) = e
        .intersect(&ray([0.0, -5.0, 10.0], [0.0, 1.0, 0.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - 3.0).abs() < 1e-12);
}

#[test]
fn cylinder_side_and_cap_hits() {
    let c = Shape::Cylinder {
        center_xz: [0.0, 10.0],
        y_min: -3.0,
        y_max: 1.0,
        radius_m: 0.5,
    };
    let (t, n) = c
        .intersect(&ray([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - 9.5).abs() < 1e-12 && (n + Vector3::z()).norm() < 1e-12);
    let (t, n) = c
        .intersect(&ray([0.2, -10.0, 10.0], [0.0, 1.0, 0.0]), 0.0, 100.0)
        .unwrap();
    assert!((t - 7.0).abs() < 1e-12 && (n + Vector3::y()).norm() < 1e-12);
    assert!(c
        .intersect(&ray([0.0, -3.5, 0.0], [0.0, 0.0, 1.0]), 0.0, 100.0)
        .is_none());
}

#[test]
fn samples_lie_on_their_surface() {
    let a = 0.6f64;
    let shapes = [
        Shape::triangle(
            Vector3::new(0.0, 0.0, 5.0),
            Vector3::new(4.0, 1.0, 5.0),
            Vector3::new(0.0, 4.0, 6.0),
        ),
        Shape::Box {
            center: Vector3::new(1.0, 2.0, 3.0),
            half_m: Vector3::new(1.0, 2.0, 0.5),
            axis: [a, (1.0 - a * a).sqrt()],
        },
        Shape::Ellipsoid {
            center: Vector3::new(0.0, 0.0, 10.0),
            radii_m: Vector3::new(2.0, 2.0, 2.0),
        },
        Shape::Cylinder {
            center_xz: [0.0, 10.0],
            y_min: -3.0,
            y_max: 1.0,
            radius_m: 0.5,
        },
    ];
    for s in shapes {
        let mut out = Vec::new();
        s.sample_surface(0.2, &mut out);
        assert!(out.len() > 20);
        for (p, n) in out {
            assert!(s.distance_to_surface(&p) < 1e-9, "{s:?} {p}");
            assert!((n.norm() - 1.0).abs() < 1e-9);
            // Stepping out along the normal leaves the solid.
            assert!(!s.contains(&(p + n * 1e-3), 0.0));
        }
    }
}
