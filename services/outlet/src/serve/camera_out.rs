//! What every camera of the sidecar publishes, one way for each frame source
//! (`sim-camera`, `files`): a frame on [`service::FRAMES`] and, with it, a
//! stereo cloud on [`service::CLOUDS`] with the same frame id and stamp, each
//! followed by the notification that wakes its readers.

use super::{Runtime, notifier};
use anyhow::Result;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use outlet::health::now_ns;
use outlet_protocol::wire::{CloudHeader, FrameHeader, PixelFormat, SCHEMA_VERSION, service};
use outlet_protocol::{CameraModel, shm};

/// Shared memory a VGA frame needs; larger frames and clouds grow it.
const VGA_BYTES: usize = 640 * 480 * 3;

pub struct CameraOutput {
    frame_service: PortFactory<ipc::Service, [u8], FrameHeader>,
    frames: Publisher<ipc::Service, [u8], FrameHeader>,
    clouds: Publisher<ipc::Service, [f32], CloudHeader>,
    frame_note: Notifier<ipc::Service>,
    cloud_note: Notifier<ipc::Service>,
}

impl CameraOutput {
    /// The publishers, first sized for `frame_bytes` of pixels and
    /// `cloud_values` f32 of cloud (each grows as needed).
    pub fn open(rt: &Runtime, frame_bytes: usize, cloud_values: usize) -> Result<Self> {
        let frame_service = shm::frames(&rt.node)?;
        let frames = frame_service
            .publisher_builder()
            .initial_max_slice_len(frame_bytes.max(1))
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| anyhow::anyhow!("frame publisher: {e:?}"))?;
        let clouds = shm::clouds(&rt.node)?
            .publisher_builder()
            .initial_max_slice_len(cloud_values.max(1))
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| anyhow::anyhow!("cloud publisher: {e:?}"))?;
        Ok(Self {
            frame_service,
            frames,
            clouds,
            frame_note: notifier(rt, service::FRAMES)?,
            cloud_note: notifier(rt, service::CLOUDS)?,
        })
    }

    /// [`Self::open`] for a VGA camera.
    pub fn open_vga(rt: &Runtime) -> Result<Self> {
        Self::open(rt, VGA_BYTES, VGA_BYTES)
    }

    /// Processes reading the frames (a detector, a recorder, ...).
    pub fn frame_readers(&self) -> usize {
        self.frame_service.dynamic_config().number_of_subscribers()
    }

    /// Publishes frame `frame_id` (`pixels`: rows of `camera.width` pixels of
    /// `format`, no padding) and then its cloud, if any; the capture stamp,
    /// taken once the pixels are in shared memory (the copy stands for the
    /// sensor's readout), goes on both. The error says which failed.
    pub fn send(
        &self,
        frame_id: u64,
        camera: &CameraModel,
        format: PixelFormat,
        pixels: &[u8],
        cloud: Option<&[[f32; 3]]>,
    ) -> Result<u64, String> {
        let f = self.frames.loan_slice_uninit(pixels.len()).map_err(|e| format!("frame: {e:?}"))?;
        let mut f = f.write_from_slice(pixels);
        let stamp = now_ns();
        *f.user_header_mut() = FrameHeader::new(frame_id, stamp, format, camera);
        f.send().map_err(|e| format!("frame: {e:?}"))?;
        let _ = self.frame_note.notify();
        if let Some(points) = cloud {
            let values = points.as_flattened();
            let mut c = self.clouds.loan_slice_uninit(values.len()).map_err(|e| format!("cloud: {e:?}"))?;
            *c.user_header_mut() = CloudHeader {
                schema_version: SCHEMA_VERSION,
                reserved: 0,
                frame_id,
                capture_time_ns: stamp,
                points: points.len() as u64,
            };
            c.write_from_slice(values).send().map_err(|e| format!("cloud: {e:?}"))?;
            let _ = self.cloud_note.notify();
        }
        Ok(stamp)
    }
}
