//! The live view: the sidecar's frames, clouds, results and health on a Foxglove
//! WebSocket server ([`outlet::live_view`]). A reader of shared memory like any
//! other: the services do not know it is there, and with no client connected it
//! converts nothing.

use super::{Runtime, clear, subscriber};
use anyhow::{Context, Result};
use iceoryx2::prelude::*;
use outlet::health::Health;
use outlet::live_view::LiveView;
use outlet_protocol::shm;
use outlet_protocol::wire::{DetectionMsg, HolePosesMsg, WallPlaneMsg, service};

pub fn run(rt: &Runtime, host: &str, port: u16) -> Result<()> {
    let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("{e:?}");
    let ctx = foxglove::Context::new();
    let view = LiveView::new(&ctx, &rt.config.ros2.frame_id).map_err(anyhow::Error::msg)?;
    let server = foxglove::WebSocketServer::new()
        .name(format!("outlet {} ({})", env!("CARGO_PKG_VERSION"), rt.config.domain))
        .bind(host, port)
        .context(&ctx)
        .start_blocking()
        .with_context(|| format!("starting the Foxglove WebSocket server on {host}:{port}"))?;
    // Port 0 asks the system for one: say which, for a client to find.
    tracing::info!(port = server.port(), "live view: open Foxglove and connect to ws://{host}:{}", server.port());
    eprintln!("outlet viewer: ws://{host}:{}", server.port());

    let node = &rt.node;
    let frames = shm::frames(node)?.subscriber_builder().create().map_err(|e| err(&e))?;
    let clouds = shm::clouds(node)?.subscriber_builder().create().map_err(|e| err(&e))?;
    let detections = subscriber::<DetectionMsg>(node, service::DETECTIONS)?;
    let poses = subscriber::<HolePosesMsg>(node, service::HOLE_POSES)?;
    let planes = subscriber::<WallPlaneMsg>(node, service::PLANES)?;
    let beats = shm::heartbeats(node)?.subscriber_builder().create().map_err(|e| err(&e))?;
    let listeners = [
        rt.listener(service::FRAMES)?,
        rt.listener(service::CLOUDS)?,
        rt.listener(service::DETECTIONS)?,
        rt.listener(service::HOLE_POSES)?,
        rt.listener(service::PLANES)?,
    ];
    let waitset = rt.waitset()?;
    let mut guards = Vec::new();
    for l in &listeners {
        guards.push(waitset.attach_notification(l).map_err(|e| err(&e))?);
    }
    let tick = waitset.attach_interval(rt.heartbeat_period()).map_err(|e| err(&e))?;
    let mut health = Health::new(rt.name);
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        if id.has_event_from(&tick) {
            rt.beat(&mut health);
            // Heartbeats carry no notification: taken on the tick.
            while let Ok(Some(b)) = beats.receive() {
                view.heartbeat(b.payload());
            }
        }
        for l in &listeners {
            clear(l);
        }
        // Only the newest frame is shown: a slow client must not hold the camera's samples.
        let mut newest = None;
        while let Ok(Some(s)) = frames.receive() {
            health.input();
            newest = Some(s);
        }
        if let Some(s) = newest {
            match view.frame(s.user_header(), s.payload()) {
                Ok(()) => health.output(s.user_header().capture_time_ns, 0.0),
                Err(reason) => {
                    health.rejected(&reason);
                    tracing::warn!("frame not shown: {reason}");
                }
            }
        }
        while let Ok(Some(s)) = clouds.receive() {
            let header = *s.user_header();
            match header.validate(s.payload().len()) {
                Ok(()) => view.cloud(&header, s.payload()),
                Err(e) => tracing::warn!("cloud not shown: {e}"),
            }
        }
        while let Ok(Some(s)) = planes.receive() {
            view.plane(s.payload());
        }
        while let Ok(Some(s)) = detections.receive() {
            view.detection(s.payload());
        }
        while let Ok(Some(s)) = poses.receive() {
            view.hole_poses(s.payload());
        }
        CallbackProgression::Continue
    };
    super::run_until_stopped(&waitset, on_event)?;
    rt.stopped(&health);
    // Clients are told goodbye before the process ends.
    server.stop().wait_blocking();
    Ok(())
}
