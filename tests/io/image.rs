//! Image helpers: PNG/PGM round trips, the real slambook2 16-bit PGM, errors naming the file.

use crate::common;

use denser::frame::Image;
use denser::io::image::{
    image_size, read_depth_pgm_u16, read_depth_png_u16, read_grey, read_pgm_u16, read_png_u16,
    read_rgb, write_depth_png_u16, write_grey_png, write_pgm_u16, write_png_u16, write_rgb_png,
};

#[test]
fn png_round_trips() {
    let tmp = tempfile::tempdir().unwrap();
    let grey = Image {
        width: 7,
        height: 3,
        data: (0..21).map(|i| (i * 12) as u8).collect(),
    };
    let p = tmp.path().join("g.png");
    write_grey_png(&p, &grey).unwrap();
    assert_eq!(read_grey(&p).unwrap(), grey);
    assert_eq!(image_size(&p).unwrap(), (7, 3));
    // Grey read as RGB replicates the channel.
    assert!(read_rgb(&p)
        .unwrap()
        .data
        .iter()
        .zip(&grey.data)
        .all(|(c, &g)| *c == [g, g, g]));

    let rgb = Image {
        width: 4,
        height: 5,
        data: (0..20).map(|i| [i as u8, 200 - i as u8, 3]).collect(),
    };
    let p = tmp.path().join("c.png");
    write_rgb_png(&p, &rgb).unwrap();
    assert_eq!(read_rgb(&p).unwrap(), rgb);
    // RGB read as grey: luma, between the channels' min and max.
    let g = read_grey(&p).unwrap();
    for (c, &l) in rgb.data.iter().zip(&g.data) {
        assert!(l >= *c.iter().min().unwrap() && l <= *c.iter().max().unwrap());
    }

    let raw = Image {
        width: 3,
        height: 2,
        data: vec![0u16, 1, 255, 256, 40000, 65535],
    };
    let p = tmp.path().join("d.png");
    write_png_u16(&p, &raw).unwrap();
    assert_eq!(read_png_u16(&p).unwrap(), raw);
    let depth = read_depth_png_u16(&p, 5000.0).unwrap();
    assert!(depth.data[0].is_nan());
    assert_eq!(depth.data[4], 8.0);
    write_depth_png_u16(&p, &depth, 5000.0).unwrap();
    assert_eq!(read_png_u16(&p).unwrap(), raw);
    // 20 m does not fit at 5000 units per metre.
    let far = Image {
        width: 1,
        height: 1,
        data: vec![20.0f32],
    };
    let e = write_depth_png_u16(tmp.path().join("far.png"), &far, 5000.0).unwrap_err();
    assert!(e.to_string().contains("13.107"), "{e}");
    assert!(read_depth_png_u16(&p, 0.0).is_err());
}

#[test]
fn pgm_round_trip_and_real_file() {
    let tmp = tempfile::tempdir().unwrap();
    let raw = Image {
        width: 5,
        height: 2,
        data: vec![0, 1, 2, 258, 1000, 9823, 65535, 7, 8, 9],
    };
    let p = tmp.path().join("d.pgm");
    write_pgm_u16(&p, &raw).unwrap();
    assert_eq!(read_pgm_u16(&p).unwrap(), raw);
    let d = read_depth_pgm_u16(&p, 1000.0).unwrap();
    assert_eq!(d.data[4], 1.0);

    let Some(dir) = common::shared_data("rgbd_5frames_slambook2") else {
        return;
    };
    let depth = read_depth_pgm_u16(dir.join("depth/1.pgm"), 1000.0).unwrap();
    assert_eq!((depth.width, depth.height), (640, 480));
    // Big-endian samples give a smooth indoor depth map in metres (SOURCE.txt: max ~9.8 m);
    // little-endian decoding would give values up to 65 m and noise between neighbours.
    let max = depth
        .data
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .fold(0.0f32, f32::max);
    assert!((5.0..10.0).contains(&max), "{max}");
    let mut jumps = 0usize;
    let mut pairs = 0usize;
    for v in 0..480 {
        for u in 0..639 {
            let (a, b) = (depth.at(u, v), depth.at(u + 1, v));
            if a.is_finite() && b.is_finite() {
                pairs += 1;
                jumps += usize::from((a - b).abs() > 0.1);
            }
        }
    }
    assert!((jumps as f64) < 0.1 * pairs as f64, "{jumps}/{pairs}");
}

#[test]
fn errors_name_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("broken.png");
    std::fs::write(&p, b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR garbage").unwrap();
    for e in [
        read_grey(&p).unwrap_err(),
        read_rgb(&p).unwrap_err(),
        read_png_u16(&p).unwrap_err(),
        image_size(&p).unwrap_err(),
    ] {
        assert!(e.to_string().contains("broken.png"), "{e}");
    }
    let e = read_grey(tmp.path().join("absent.png"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("absent.png"), "{e}");
    let rgb = Image {
        width: 2,
        height: 2,
        data: vec![[1u8, 2, 3]; 4],
    };
    let c = tmp.path().join("colour.png");
    write_rgb_png(&c, &rgb).unwrap();
    let e = read_depth_png_u16(&c, 1000.0).unwrap_err().to_string();
    assert!(e.contains("colour.png") && e.contains("16-bit"), "{e}");
    let pgm = tmp.path().join("short.pgm");
    std::fs::write(&pgm, b"P5\n4 4\n65535\n\0\0\0").unwrap();
    let e = read_pgm_u16(&pgm).unwrap_err().to_string();
    assert!(e.contains("short.pgm") && e.contains("truncated"), "{e}");
    let wrong = Image {
        width: 3,
        height: 3,
        data: vec![0u8; 4],
    };
    assert!(write_grey_png(tmp.path().join("w.png"), &wrong).is_err());
}

/// Issue 13: JPEG, TIFF, PNM, BMP and WebP inputs read as PNG does; 16-bit TIFF depth round trip.
#[test]
fn other_formats_read_like_png() {
    use image::{ImageBuffer, ImageFormat, Luma, Rgb};
    let tmp = tempfile::tempdir().unwrap();
    let (w, h) = (64u32, 48u32);
    // A smooth colour ramp (JPEG keeps it within a few levels).
    let rgb: ImageBuffer<Rgb<u8>, Vec<u8>> = ImageBuffer::from_fn(w, h, |x, y| {
        Rgb([(x * 4) as u8, (y * 5) as u8, ((x + y) * 2) as u8])
    });
    for (name, fmt, lossless) in [
        ("c.png", ImageFormat::Png, true),
        ("c.jpg", ImageFormat::Jpeg, false),
        ("c.tif", ImageFormat::Tiff, true),
        ("c.ppm", ImageFormat::Pnm, true),
        ("c.bmp", ImageFormat::Bmp, true),
        ("c.webp", ImageFormat::WebP, true),
    ] {
        let p = tmp.path().join(name);
        rgb.save_with_format(&p, fmt).unwrap();
        let back = read_rgb(&p).unwrap();
        assert_eq!((back.width, back.height), (w, h), "{name}");
        assert_eq!(image_size(&p).unwrap(), (w, h), "{name}");
        let worst = back
            .data
            .iter()
            .zip(rgb.pixels())
            .flat_map(|(a, b)| (0..3).map(move |k| (a[k] as i32 - b.0[k] as i32).abs()))
            .max()
            .unwrap();
        if lossless {
            assert_eq!(worst, 0, "{name}");
        } else {
            assert!(worst <= 12, "{name}: {worst}");
        }
        let grey = read_grey(&p).unwrap();
        assert_eq!(grey.data.len(), (w * h) as usize, "{name}");
    }
    // 16-bit depth as TIFF and as PGM through the image crate's reader.
    let depth: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_fn(w, h, |x, y| Luma([(x * 1000 + y) as u16]));
    let tif = tmp.path().join("d.tif");
    depth.save_with_format(&tif, ImageFormat::Tiff).unwrap();
    let back = denser::io::image::read_u16(&tif).unwrap();
    assert_eq!(back.data, depth.as_raw().clone());
    let d = denser::io::image::read_depth_u16(&tif, 1000.0).unwrap();
    assert!(d.data[0].is_nan()); // sample 0 = no depth
    assert_eq!(d.data[1], 1.0); // x = 1: 1000 units = 1 m
    let pgm = tmp.path().join("d.pgm");
    write_pgm_u16(
        &pgm,
        &Image {
            width: w,
            height: h,
            data: depth.as_raw().clone(),
        },
    )
    .unwrap();
    assert_eq!(
        denser::io::image::read_depth_u16(&pgm, 1000.0)
            .unwrap()
            .data[1..],
        d.data[1..]
    );
    // Not an image at all: the message names the file and the formats.
    let txt = tmp.path().join("notes.jpg");
    std::fs::write(&txt, "hello").unwrap();
    let e = read_grey(&txt).unwrap_err().to_string();
    assert!(e.contains("notes.jpg") && e.contains("decode"), "{e}");
    // Frame folders find any format.
    assert_eq!(
        denser::io::image::find_image(tmp.path(), "c").unwrap(),
        tmp.path().join("c.png")
    );
}
