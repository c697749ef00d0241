//! A stereo input's pairs turned into depth frames, one way for every stereo source (KITTI
//! layouts, ROS 2 bags): matched, and either handed on where the matcher left them (the
//! depths stay on the GPU for the fusion: [`crate::fusion::DeviceDepthFrame`]) or read back and
//! converted on the host, `z = fx·B/d`.

use super::sequence::RangeInput;
use crate::depth::{disparity_to_depth, DisparityEstimator};
use crate::frame::{DepthFrame, GreyImage};
use crate::fusion::{CameraView, DepthFusionParams, DeviceDepthFrame, DeviceDepthKept};
use crate::grid::GridParams;
use crate::Result;
use std::sync::Mutex;

/// A matcher and where its depths go (see the module documentation).
pub(crate) struct StereoDepth {
    estimator: Box<dyn DisparityEstimator>,
    /// [`super::sequence::InputOptions::depth_on_device`].
    on_device: Option<(GridParams, DepthFusionParams)>,
    /// What the frames made on the device keep between pairs.
    kept: Mutex<DeviceDepthKept>,
}

impl StereoDepth {
    /// `estimator`'s depths, kept on its device for a fusion of `on_device` where it can.
    pub(crate) fn new(
        estimator: Box<dyn DisparityEstimator>,
        on_device: Option<(GridParams, DepthFusionParams)>,
    ) -> Self {
        StereoDepth {
            estimator,
            on_device,
            kept: Mutex::default(),
        }
    }

    /// The matcher's name.
    pub(crate) fn name(&self) -> &str {
        self.estimator.name()
    }

    /// The depth frame of the rectified pair `left`, `right` of cameras `baseline_m` apart,
    /// seen as `view` (the left camera of the images' size, its pose, its colour): on the
    /// device where the matcher can leave it there and a fusion was named, else on the host.
    pub(crate) fn frame(
        &self,
        (left, right): (&GreyImage, &GreyImage),
        view: CameraView,
        baseline_m: f64,
    ) -> Result<RangeInput> {
        let mut view = Some(view);
        if let Some((grid, params)) = &self.on_device {
            // The colour waits on the host for the fusion.
            let mut made = None;
            let mut kept = self.kept.lock().unwrap_or_else(|e| e.into_inner());
            // The matcher writes its buffers now: the pair before goes first if still held.
            kept.submit_held();
            let ran = self.estimator.estimate_on_device(left, right, &mut |d| {
                let view = view.take().expect("one map per pair");
                let frame = DeviceDepthFrame::from_on_device(
                    d,
                    (grid, params),
                    view,
                    baseline_m,
                    &mut kept,
                );
                made = Some(frame?);
                Ok(())
            });
            if let Some(ran) = ran {
                ran?;
                let frame = made.expect("made by the matcher's hand-on");
                return Ok(RangeInput::DeviceDepth(Box::new(frame)));
            }
        }
        let (intrinsics, world_from_camera, color) = view.expect("not handed on");
        let disparity = self.estimator.estimate(left, right)?;
        let depth_m = disparity_to_depth(&disparity, intrinsics.fx, baseline_m);
        Ok(RangeInput::Depth(DepthFrame {
            intrinsics,
            world_from_camera,
            depth_m,
            color,
        }))
    }
}
