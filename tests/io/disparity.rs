//! KITTI disparity PNG, the format-picking reader, and LiDAR-derived disparity ground truth.
use denser::camera::PinholeIntrinsics;
use denser::depth::disparity_from_points;
use denser::depth::disparity_io::{
    read_disparity, read_kitti_disparity_png, write_kitti_disparity_png,
};
use denser::frame::Image;

#[test]
fn kitti_png_round_trip_quantises_to_1_256() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("000000_10.png");
    let data = vec![0.0, 12.3456, f32::NAN, 255.99, -4.0, 1.0 / 256.0];
    let img = Image {
        width: 3,
        height: 2,
        data: data.clone(),
    };
    write_kitti_disparity_png(&path, &img).unwrap();
    let back = read_kitti_disparity_png(&path).unwrap();
    assert_eq!((back.width, back.height), (3, 2));
    assert!(back.data[0].is_nan() && back.data[2].is_nan() && back.data[4].is_nan());
    assert_eq!(back.data[1], (12.3456f32 * 256.0).round() / 256.0);
    assert_eq!(back.data[3], (255.99f32 * 256.0).round() / 256.0);
    assert_eq!(back.data[5], 1.0 / 256.0);
    // The raw file holds value·256 in 16 bits.
    let raw = image::open(&path).unwrap().to_luma16();
    assert_eq!(
        raw.get_pixel(1, 0).0[0],
        (12.3456f64 * 256.0).round() as u16
    );
    // The extension picks the format.
    assert_eq!(read_disparity(&path).unwrap().data[1], back.data[1]);
    let pfm = dir.path().join("d.pfm");
    denser::io::pfm::write_pfm(&pfm, &back).unwrap();
    assert_eq!(read_disparity(&pfm).unwrap().data[3], back.data[3]);
}

#[test]
fn kitti_png_bad_input_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let eight_bit = dir.path().join("eight.png");
    image::GrayImage::from_pixel(4, 3, image::Luma([9]))
        .save(&eight_bit)
        .unwrap();
    let err = read_kitti_disparity_png(&eight_bit)
        .unwrap_err()
        .to_string();
    assert!(err.contains("eight.png") && err.contains("16-bit"), "{err}");
    let garbage = dir.path().join("garbage.png");
    std::fs::write(&garbage, b"not a png at all").unwrap();
    let err = read_kitti_disparity_png(&garbage).unwrap_err().to_string();
    assert!(err.contains("garbage.png") && err.contains("PNG"), "{err}");
    let err = read_disparity(dir.path().join("d.tiff"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("d.tiff") && err.contains(".pfm"), "{err}");
}

#[test]
fn lidar_plane_gives_fb_over_z_disparity() {
    // A fronto-parallel wall at z = 20 m sampled densely (finer than a pixel), plus points of a
    // nearer pole at z = 8 m in front of part of it: the z-buffer keeps the pole.
    let k = PinholeIntrinsics {
        fx: 718.856,
        fy: 718.856,
        cx: 607.19,
        cy: 185.22,
        width: 1241,
        height: 376,
    };
    let b = 0.537;
    let mut points = Vec::new();
    for i in 0..400 {
        for j in 0..100 {
            points.push([-4.0 + i as f64 * 0.02, -1.0 + j as f64 * 0.02, 20.0]);
        }
    }
    for j in 0..40 {
        points.push([0.0, -0.4 + j as f64 * 0.02, 8.0]);
    }
    let d = disparity_from_points(&points, &k, b);
    let wall = (k.fx * b / 20.0) as f32;
    let pole = (k.fx * b / 8.0) as f32;
    // Pole column: u = cx + fx·0/8 → 607; a row it covers: y = 0 → v = 185.
    assert_eq!(d.at(607, 185), pole);
    // Wall pixel away from the pole: x = 2 m → u = cx + fx·2/20 ≈ 679, y = 0 → v = 185.
    assert_eq!(d.at(679, 185), wall);
    let valid: Vec<f32> = d.data.iter().copied().filter(|v| v.is_finite()).collect();
    assert!(valid.iter().all(|&v| v == wall || v == pole));
    assert!(valid.len() > 10_000, "{} pixels", valid.len());
}
