use super::*;

#[test]
fn nearest_rotation_snaps_and_rejects() {
    let r = Rotation3::from_euler_angles(0.1, -0.2, 0.3);
    let mut m = Matrix3x4::zeros();
    m.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(r.matrix() * 1.000001));
    m[(0, 3)] = 5.0;
    let iso = isometry_from_3x4(&m).unwrap();
    assert!((iso.rotation.to_rotation_matrix().matrix() - r.matrix()).norm() < 1e-5);
    assert_eq!(iso.translation.vector.x, 5.0);
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-r.matrix()));
    assert!(isometry_from_3x4(&m).unwrap_err().contains("reflection"));
    m.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(r.matrix() * 1.5));
    assert!(isometry_from_3x4(&m).unwrap_err().contains("orthonormal"));
}
