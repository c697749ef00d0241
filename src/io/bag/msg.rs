//! The ROS 2 messages `denser` reads from a bag, as serde structs decoded from CDR by the `cdr`
//! crate (the encapsulation header picks the byte order), and their conversion to the crate's
//! types. Field order and types follow the ROS 2 message definitions (Humble and later); a
//! struct may stop before the message's last fields (the rest is not read).

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde::Deserialize;

/// `builtin_interfaces/msg/Time`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds, 0 ≤ nanosec < 10⁹.
    pub nanosec: u32,
}

impl Time {
    /// The time in nanoseconds (may be 0 for "unset").
    pub fn ns(self) -> i64 {
        self.sec as i64 * 1_000_000_000 + self.nanosec as i64
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct Header {
    /// Acquisition time.
    pub stamp: Time,
    /// The frame the data is in.
    pub frame_id: String,
}

/// A CDR `sequence<uint8>` read in one piece (serde's `Vec<u8>` would read byte by byte).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Bytes(pub Vec<u8>);

impl<'de> Deserialize<'de> for Bytes {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = Bytes;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a byte sequence")
            }
            fn visit_byte_buf<E>(self, v: Vec<u8>) -> Result<Bytes, E> {
                Ok(Bytes(v))
            }
            fn visit_bytes<E>(self, v: &[u8]) -> Result<Bytes, E> {
                Ok(Bytes(v.to_vec()))
            }
        }
        d.deserialize_byte_buf(V)
    }
}

/// `sensor_msgs/msg/PointField`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct PointField {
    /// Field name (`x`, `intensity`, …).
    pub name: String,
    /// Byte offset in a point.
    pub offset: u32,
    /// 1 INT8, 2 UINT8, 3 INT16, 4 UINT16, 5 INT32, 6 UINT32, 7 FLOAT32, 8 FLOAT64.
    pub datatype: u8,
    /// Elements in the field.
    pub count: u32,
}

/// `sensor_msgs/msg/PointCloud2`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct PointCloud2 {
    /// Time and frame of the scan.
    pub header: Header,
    /// Rows (1 for an unorganised cloud).
    pub height: u32,
    /// Points per row.
    pub width: u32,
    /// The point's fields.
    pub fields: Vec<PointField>,
    /// Byte order of `data`.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// The points.
    pub data: Bytes,
}

/// `geometry_msgs/msg/Vector3` and `Point` (same layout).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct Quat {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// `geometry_msgs/msg/Transform` and `Pose` (translation/position, then rotation/orientation).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct Transform {
    /// Translation (position), metres.
    pub translation: Vector3,
    /// Rotation (orientation).
    pub rotation: Quat,
}

impl Transform {
    /// As an isometry; `None` when a value is not finite or the quaternion is far from unit
    /// length (it is normalised otherwise).
    pub fn isometry(&self) -> Option<Isometry3<f64>> {
        let t = self.translation;
        let r = self.rotation;
        let q = Quaternion::new(r.w, r.x, r.y, r.z);
        let n = q.norm();
        let finite = [t.x, t.y, t.z, r.x, r.y, r.z, r.w]
            .iter()
            .all(|v| v.is_finite());
        (finite && (0.5..=1.5).contains(&n)).then(|| {
            Isometry3::from_parts(
                Translation3::new(t.x, t.y, t.z),
                UnitQuaternion::from_quaternion(q),
            )
        })
    }
}

/// `geometry_msgs/msg/TransformStamped`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct TransformStamped {
    /// Time, and the parent frame.
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// `parent_from_child`.
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage` (`/tf`, `/tf_static`).
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

/// `geometry_msgs/msg/PoseStamped`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct PoseStamped {
    /// Time, and the frame the pose is in.
    pub header: Header,
    /// The pose.
    pub pose: Transform,
}

/// `nav_msgs/msg/Odometry`, up to its pose (covariance and twist are not read).
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct Odometry {
    /// Time, and the frame the pose is in.
    pub header: Header,
    /// The frame whose pose it is.
    pub child_frame_id: String,
    /// The pose (`PoseWithCovariance.pose`).
    pub pose: Transform,
}

/// Decodes a CDR message (with its 4-byte encapsulation header).
pub fn decode<'de, T: Deserialize<'de>>(bytes: &[u8]) -> Result<T, String> {
    cdr::deserialize::<T>(bytes).map_err(|e| format!("CDR: {e}"))
}

/// The ROS 2 type names `denser` knows.
pub mod types {
    /// A point cloud.
    pub const POINT_CLOUD2: &str = "sensor_msgs/msg/PointCloud2";
    /// Transforms (`/tf`, `/tf_static`).
    pub const TF: &str = "tf2_msgs/msg/TFMessage";
    /// Odometry.
    pub const ODOMETRY: &str = "nav_msgs/msg/Odometry";
    /// A stamped pose.
    pub const POSE_STAMPED: &str = "geometry_msgs/msg/PoseStamped";
    /// A raw image.
    pub const IMAGE: &str = "sensor_msgs/msg/Image";
    /// A compressed image.
    pub const COMPRESSED_IMAGE: &str = "sensor_msgs/msg/CompressedImage";
    /// Camera calibration.
    pub const CAMERA_INFO: &str = "sensor_msgs/msg/CameraInfo";
}

/// Points of a cloud as `[x, y, z]` f32 and intensity (empty without an `intensity` field);
/// non-finite points are dropped. Errors describe what is wrong with the layout.
pub fn cloud_points(c: &PointCloud2) -> Result<(Vec<[f32; 3]>, Vec<f32>), String> {
    let n = c.width as usize * c.height as usize;
    let step = c.point_step as usize;
    let field = |name: &str| c.fields.iter().find(|f| f.name == name);
    let reader = |f: &PointField| -> Result<(usize, u8), String> {
        let size = match f.datatype {
            1 | 2 => 1,
            3 | 4 => 2,
            5..=7 => 4,
            8 => 8,
            d => return Err(format!("field {} has unknown datatype {d}", f.name)),
        };
        if f.offset as usize + size > step {
            return Err(format!(
                "field {} (offset {}, {size} bytes) runs past the point step {step}",
                f.name, f.offset
            ));
        }
        Ok((f.offset as usize, f.datatype))
    };
    let (Some(fx), Some(fy), Some(fz)) = (field("x"), field("y"), field("z")) else {
        let names: Vec<&str> = c.fields.iter().map(|f| f.name.as_str()).collect();
        return Err(format!("the cloud's fields {names:?} lack one of x, y, z"));
    };
    let xyz = [reader(fx)?, reader(fy)?, reader(fz)?];
    let intensity = field("intensity").map(reader).transpose()?;
    let row = c.row_step as usize;
    if row < c.width as usize * step || c.data.0.len() < row * c.height as usize {
        return Err(format!(
            "{} bytes of data for {} × {} points of {step} bytes (row step {row})",
            c.data.0.len(),
            c.height,
            c.width
        ));
    }
    let big = c.is_bigendian;
    let value = |p: &[u8], (off, ty): (usize, u8)| -> f64 {
        let b = &p[off..];
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().unwrap();
                (if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }) as f64
            }};
        }
        match ty {
            1 => b[0] as i8 as f64,
            2 => b[0] as f64,
            3 => num!(i16, 2),
            4 => num!(u16, 2),
            5 => num!(i32, 4),
            6 => num!(u32, 4),
            7 => num!(f32, 4),
            _ => num!(f64, 8),
        }
    };
    let mut points = Vec::with_capacity(n);
    let mut values = Vec::with_capacity(if intensity.is_some() { n } else { 0 });
    for r in 0..c.height as usize {
        let line = &c.data.0[r * row..];
        for k in 0..c.width as usize {
            let p = &line[k * step..(k + 1) * step];
            let v = xyz.map(|f| value(p, f));
            if v.iter().all(|x| x.is_finite()) {
                points.push([v[0] as f32, v[1] as f32, v[2] as f32]);
                if let Some(f) = intensity {
                    values.push(value(p, f) as f32);
                }
            }
        }
    }
    Ok((points, values))
}

/// `sensor_msgs/msg/Image`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct RawImage {
    /// Time and camera frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`mono8`, `rgb8`, `bgr8`, `rgba8`, `bgra8`, `mono16`).
    pub encoding: String,
    /// Byte order of 16-bit encodings (0: little-endian).
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// The pixels.
    pub data: Bytes,
}

/// `sensor_msgs/msg/CompressedImage`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct CompressedImage {
    /// Time and camera frame.
    pub header: Header,
    /// `png`, `jpeg`, or image_transport's `mono8; png compressed …`.
    pub format: String,
    /// The encoded image.
    pub data: Bytes,
}

/// `sensor_msgs/msg/CameraInfo`, up to the projection matrix.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct CameraInfo {
    /// Time and camera frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// `plumb_bob`, `rational_polynomial`, `equidistant`, or empty.
    pub distortion_model: String,
    /// Distortion coefficients of the raw image.
    pub d: Vec<f64>,
    /// Intrinsics of the raw image, row-major 3×3.
    pub k: [f64; 9],
    /// Rectification rotation, row-major 3×3.
    pub r: [f64; 9],
    /// Projection of the rectified image, row-major 3×4.
    pub p: [f64; 12],
}

/// An image message of either kind, decoded (raw encodings copied row by row; BGR reordered;
/// 16-bit grey kept at 16 bits).
pub fn image_dynamic(type_name: &str, data: &[u8]) -> Result<image::DynamicImage, String> {
    use image::{DynamicImage, ImageBuffer};
    if type_name == types::COMPRESSED_IMAGE {
        let m: CompressedImage = decode(data)?;
        return image::load_from_memory(&m.data.0)
            .map_err(|e| format!("compressed image ({}): {e}", m.format));
    }
    let m: RawImage = decode(data)?;
    let (w, h) = (m.width as usize, m.height as usize);
    let channels = match m.encoding.as_str() {
        "mono8" | "8UC1" => 1,
        "mono16" | "16UC1" => 2,
        "rgb8" | "bgr8" => 3,
        "rgba8" | "bgra8" => 4,
        e => {
            return Err(format!(
                "image encoding '{e}' is not read (mono8, mono16, rgb8, bgr8, rgba8, bgra8)"
            ))
        }
    };
    let step = m.step as usize;
    if step < w * channels || m.data.0.len() < step * h {
        return Err(format!(
            "{} bytes for {w}×{h} '{}' pixels (step {step})",
            m.data.0.len(),
            m.encoding
        ));
    }
    let mut packed = Vec::with_capacity(w * h * channels);
    for row in m.data.0.chunks(step).take(h) {
        packed.extend_from_slice(&row[..w * channels]);
    }
    let bgr = m.encoding.starts_with("bgr");
    if bgr {
        for px in packed.chunks_exact_mut(channels) {
            px.swap(0, 2);
        }
    }
    let size = format!("{w}×{h}");
    let bad = || format!("{size} '{}' pixels do not fill the image", m.encoding);
    Ok(match channels {
        1 => DynamicImage::ImageLuma8(
            ImageBuffer::from_raw(m.width, m.height, packed).ok_or_else(bad)?,
        ),
        2 => {
            let px: Vec<u16> = packed
                .chunks_exact(2)
                .map(|b| {
                    if m.is_bigendian != 0 {
                        u16::from_be_bytes([b[0], b[1]])
                    } else {
                        u16::from_le_bytes([b[0], b[1]])
                    }
                })
                .collect();
            DynamicImage::ImageLuma16(ImageBuffer::from_raw(m.width, m.height, px).ok_or_else(bad)?)
        }
        3 => DynamicImage::ImageRgb8(
            ImageBuffer::from_raw(m.width, m.height, packed).ok_or_else(bad)?,
        ),
        _ => DynamicImage::ImageRgba8(
            ImageBuffer::from_raw(m.width, m.height, packed).ok_or_else(bad)?,
        ),
    })
}
