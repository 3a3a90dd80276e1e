//! The typed results: [`HolePoses`] with its [`Hole`]s, and [`Heartbeat`].

use crate::error::Rejection;
use outlet_protocol::HoleKind;
use outlet_protocol::wire::{HeartbeatMsg, HolePosesMsg, SCHEMA_VERSION, WireError, pose_status};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// The time `ns` nanoseconds after the Unix epoch.
pub(crate) fn time_from_ns(ns: u64) -> SystemTime {
    // u64 nanoseconds reach the year 2554, which SystemTime holds on every
    // platform iceoryx2 runs on; fall back to the epoch rather than panic.
    UNIX_EPOCH.checked_add(Duration::from_nanos(ns)).unwrap_or(UNIX_EPOCH)
}

/// What the pose was solved with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PoseMode {
    /// From the hole pixels alone (planar PnP).
    Mono,
    /// With a known wall normal (the paper's closed form).
    Normal,
    /// With the wall plane (normal and distance) fitted to the stereo cloud.
    Plane,
}

impl PoseMode {
    /// The mode of a wire code (1 mono, 2 normal, 3 plane).
    pub fn from_code(code: u32) -> Option<Self> {
        match code {
            1 => Some(Self::Mono),
            2 => Some(Self::Normal),
            3 => Some(Self::Plane),
            _ => None,
        }
    }

    /// The wire code of the mode (1 mono, 2 normal, 3 plane).
    pub fn code(self) -> u32 {
        match self {
            Self::Mono => 1,
            Self::Normal => 2,
            Self::Plane => 3,
        }
    }

    /// `mono`, `normal` or `plane`, as `outlet detect --json` writes it.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Mono => "mono",
            Self::Normal => "normal",
            Self::Plane => "plane",
        }
    }
}

/// Whether a result holds a pose to act on.
///
/// Only [`PoseStatus::Ok`] results carry holes; the others say why there is no
/// pose this frame, so that a controller can tell "nothing trustworthy" from
/// "nothing seen". The sidecar never replaces a pose it cannot trust with a
/// quieter guess.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PoseStatus {
    /// The holes and the pose hold within their covariances.
    Ok,
    /// From the pixels alone (mono), two mirror-image poses explain the holes
    /// about equally: the outlet is small or seen too squarely to choose. No
    /// holes; move closer or give the sidecar a stereo cloud.
    Ambiguous,
    /// A wall plane was measured but cannot explain the detected holes (a hole
    /// found in the wrong place, or a plane of something else). No holes.
    PlaneMismatch,
}

impl PoseStatus {
    /// The status of a wire code ([`pose_status`]: 1 ok, 2 ambiguous, 3 plane mismatch).
    pub fn from_code(code: u32) -> Option<Self> {
        match code {
            pose_status::OK => Some(Self::Ok),
            pose_status::AMBIGUOUS => Some(Self::Ambiguous),
            pose_status::PLANE_MISMATCH => Some(Self::PlaneMismatch),
            _ => None,
        }
    }

    /// The wire code of the status.
    pub fn code(self) -> u32 {
        match self {
            Self::Ok => pose_status::OK,
            Self::Ambiguous => pose_status::AMBIGUOUS,
            Self::PlaneMismatch => pose_status::PLANE_MISMATCH,
        }
    }

    /// `ok`, `ambiguous` or `plane_mismatch`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::Ambiguous => "ambiguous",
            Self::PlaneMismatch => "plane_mismatch",
        }
    }
}

/// One hole of the outlet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hole {
    /// What the hole receives.
    pub kind: HoleKind,
    /// Its centre on the receptacle face: camera frame, metres.
    pub position_m: [f64; 3],
    /// The covariance of `position_m` (camera frame, m²), rows then columns.
    pub covariance_m2: [[f64; 3]; 3],
    /// The hole's pixel could not be explained with the others and was not used:
    /// its position comes from the other holes through the outlet's geometry
    /// (and its covariance says how well).
    pub outlier: bool,
}

impl Hole {
    /// The standard deviation of the position along the camera's x, y and z
    /// axes (metres): the square roots of the covariance's diagonal.
    pub fn std_dev_m(&self) -> [f64; 3] {
        std::array::from_fn(|k| self.covariance_m2[k][k].max(0.0).sqrt())
    }
}

/// A hole's uncertainty split the way an arm inserts: along the outlet's face
/// normal (how far in), and in the face plane (where to aim). An arm can come
/// in head-on while the in-plane error is large and insert once it is small.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceErrors {
    /// Standard deviation along the face normal (metres).
    pub normal_sigma_m: f64,
    /// Standard deviations along the outlet frame's x and y axes in the face
    /// plane (metres).
    pub in_plane_sigma_m: [f64; 2],
    /// The largest standard deviation in any direction of the face plane
    /// (metres): the in-plane 2x2 covariance's larger eigenvalue, square-rooted.
    pub in_plane_max_sigma_m: f64,
}

impl FaceErrors {
    /// The split of a camera-frame covariance (m²) for an outlet whose frame
    /// turns into the camera's by `rotation` (its z axis the face normal).
    /// `None` when the rotation or covariance is not finite.
    pub fn of(covariance_m2: &[[f64; 3]; 3], rotation: &[[f64; 3]; 3]) -> Option<Self> {
        let finite = covariance_m2.iter().chain(rotation).flatten().all(|v| v.is_finite());
        if !finite {
            return None;
        }
        // Column k of the rotation is the outlet's axis k in the camera frame.
        let axis = |k: usize| [rotation[0][k], rotation[1][k], rotation[2][k]];
        let quad = |a: [f64; 3], b: [f64; 3]| {
            (0..3).map(|r| (0..3).map(|c| a[r] * covariance_m2[r][c] * b[c]).sum::<f64>()).sum::<f64>()
        };
        let (x, y, z) = (axis(0), axis(1), axis(2));
        let (xx, yy, xy) = (quad(x, x), quad(y, y), quad(x, y));
        // Larger eigenvalue of [[xx, xy], [xy, yy]].
        let half_trace = (xx + yy) / 2.0;
        let largest = half_trace + (((xx - yy) / 2.0).powi(2) + xy * xy).sqrt();
        Some(Self {
            normal_sigma_m: quad(z, z).max(0.0).sqrt(),
            in_plane_sigma_m: [xx.max(0.0).sqrt(), yy.max(0.0).sqrt()],
            in_plane_max_sigma_m: largest.max(0.0).sqrt(),
        })
    }
}

/// The pose service's result for one frame: where the outlet and its holes are.
#[derive(Debug, Clone, PartialEq)]
pub struct HolePoses {
    /// The camera frame the result was computed from.
    pub frame_id: u64,
    /// When that frame was captured.
    pub capture_time: SystemTime,
    /// When the pose service published the result.
    pub published: SystemTime,
    /// When this client took it out of shared memory.
    pub received: SystemTime,
    /// What the pose was solved with (or, when `status` is not
    /// [`PoseStatus::Ok`], what was tried).
    pub mode: PoseMode,
    /// Whether there is a pose to act on; check it before `holes`.
    pub status: PoseStatus,
    /// The outlet's orientation: rotation from the outlet frame (`CONTRACT.md`)
    /// to the camera frame, `rotation[row][column]`; NaN unless `status` is
    /// [`PoseStatus::Ok`].
    pub rotation: [[f64; 3]; 3],
    /// The outlet frame's origin in the camera frame (metres); NaN unless
    /// `status` is [`PoseStatus::Ok`].
    pub translation_m: [f64; 3],
    /// The holes, in the template's order; empty unless `status` is
    /// [`PoseStatus::Ok`].
    pub holes: Vec<Hole>,
}

impl HolePoses {
    /// Checks a message from shared memory and converts it; `received` is when it
    /// was taken out. Refuses what [`HolePosesMsg::validate`] refuses (schema
    /// version, hole count above [`MAX_HOLES`](outlet_protocol::wire::MAX_HOLES),
    /// non-finite positions, unknown status, holes in a result without a pose),
    /// unknown mode or hole kind codes, and a non-finite rotation or translation
    /// in a result with a pose. Covariances are passed on as they are.
    pub fn from_msg(msg: &HolePosesMsg, received: SystemTime) -> Result<Self, Rejection> {
        msg.validate()?;
        let frame_id = msg.frame_id;
        let mode = PoseMode::from_code(msg.mode).ok_or(Rejection::UnknownMode { frame_id, code: msg.mode })?;
        // validate() has refused unknown status codes.
        let status =
            PoseStatus::from_code(msg.status).ok_or(WireError::Result { frame_id, reason: "unknown status" })?;
        if status == PoseStatus::Ok && !msg.rotation.iter().chain(&msg.translation_m).all(|v| v.is_finite()) {
            return Err(Rejection::PoseNotFinite { frame_id });
        }
        // validate() has checked hole_count <= MAX_HOLES; take() keeps this safe regardless.
        let count = msg.hole_count as usize;
        let mut holes = Vec::with_capacity(count);
        for (index, ((&code, &position_m), covariance)) in
            msg.kinds.iter().zip(&msg.positions_m).zip(&msg.covariances_m2).enumerate().take(count)
        {
            let kind = match code {
                1 => HoleKind::Power,
                2 => HoleKind::Ground,
                _ => return Err(Rejection::UnknownHoleKind { frame_id, index, code }),
            };
            let covariance_m2 = std::array::from_fn(|r| std::array::from_fn(|c| covariance[3 * r + c]));
            let outlier = index < 32 && msg.outlier_mask & (1 << index) != 0;
            holes.push(Hole { kind, position_m, covariance_m2, outlier });
        }
        Ok(Self {
            frame_id,
            capture_time: time_from_ns(msg.capture_time_ns),
            published: time_from_ns(msg.published_ns),
            received,
            mode,
            status,
            rotation: std::array::from_fn(|r| std::array::from_fn(|c| msg.rotation[3 * r + c])),
            translation_m: msg.translation_m,
            holes,
        })
    }

    /// Hole `index`'s uncertainty along the face normal and in the face plane;
    /// `None` without a pose or such a hole.
    pub fn face_errors(&self, index: usize) -> Option<FaceErrors> {
        let hole = self.holes.get(index)?;
        if !self.is_usable() {
            return None;
        }
        FaceErrors::of(&hole.covariance_m2, &self.rotation)
    }

    /// Whether the result holds a pose to act on ([`PoseStatus::Ok`]).
    pub fn is_usable(&self) -> bool {
        self.status == PoseStatus::Ok
    }

    /// How old the result is now: the time since its frame was captured (zero if
    /// the capture time lies in the future).
    pub fn age(&self) -> Duration {
        self.age_at(SystemTime::now())
    }

    /// How old the result is at `now` (zero if captured after `now`).
    pub fn age_at(&self, now: SystemTime) -> Duration {
        now.duration_since(self.capture_time).unwrap_or(Duration::ZERO)
    }

    /// From capture to publication: how long the sidecar took for this frame.
    pub fn latency(&self) -> Duration {
        self.published.duration_since(self.capture_time).unwrap_or(Duration::ZERO)
    }
}

/// One service's health, from its latest heartbeat.
#[derive(Debug, Clone, PartialEq)]
pub struct Heartbeat {
    /// The service's name (`detector`, `normal`, `pose`, `sim-camera`, ...).
    pub service: String,
    /// Its process id.
    pub pid: u32,
    /// The heartbeat's number, counting from the service's start.
    pub sequence: u64,
    /// When the service started.
    pub started: SystemTime,
    /// When the service published this heartbeat.
    pub published: SystemTime,
    /// When this client took it out of shared memory.
    pub received: SystemTime,
    /// Inputs taken since the service started.
    pub inputs: u64,
    /// Outputs published since the service started.
    pub outputs: u64,
    /// Inputs refused since the service started.
    pub rejected: u64,
    /// Inputs skipped because a newer one was already waiting.
    pub dropped: u64,
    /// Inputs per second over the last period.
    pub input_rate_hz: f64,
    /// Outputs per second over the last period.
    pub output_rate_hz: f64,
    /// Capture to publish, median over the last period; `None` when nothing went out.
    pub latency_p50: Option<Duration>,
    /// Capture to publish, 99th percentile over the last period.
    pub latency_p99: Option<Duration>,
    /// Capture to publish, maximum over the last period.
    pub latency_max: Option<Duration>,
    /// The service's own work per input, median over the last period.
    pub work_p50: Option<Duration>,
    /// The service's own work per input, 99th percentile over the last period.
    pub work_p99: Option<Duration>,
    /// When the service's last output went out; `None` if it never published.
    pub last_output: Option<SystemTime>,
    /// Why the service refused its last refused input; `None` if it never refused one.
    pub last_rejection: Option<String>,
}

/// A duration from milliseconds; `None` for NaN (nothing measured), negative or
/// infinite values.
fn millis(ms: f64) -> Option<Duration> {
    Duration::try_from_secs_f64(ms / 1000.0).ok()
}

impl Heartbeat {
    /// Checks the schema version of a heartbeat from shared memory and converts
    /// it; `received` is when it was taken out.
    pub fn from_msg(msg: &HeartbeatMsg, received: SystemTime) -> Result<Self, Rejection> {
        if msg.schema_version != SCHEMA_VERSION {
            return Err(WireError::Schema { found: msg.schema_version, expected: SCHEMA_VERSION }.into());
        }
        let last_rejection = msg.last_rejection();
        Ok(Self {
            service: msg.service_name().to_string(),
            pid: msg.pid,
            sequence: msg.sequence,
            started: time_from_ns(msg.started_ns),
            published: time_from_ns(msg.published_ns),
            received,
            inputs: msg.inputs,
            outputs: msg.outputs,
            rejected: msg.rejected,
            dropped: msg.dropped,
            input_rate_hz: msg.input_rate_hz,
            output_rate_hz: msg.output_rate_hz,
            latency_p50: millis(msg.latency_p50_ms),
            latency_p99: millis(msg.latency_p99_ms),
            latency_max: millis(msg.latency_max_ms),
            work_p50: millis(msg.work_p50_ms),
            work_p99: millis(msg.work_p99_ms),
            last_output: (msg.last_output_ns != 0).then(|| time_from_ns(msg.last_output_ns)),
            last_rejection: (!last_rejection.is_empty()).then(|| last_rejection.to_string()),
        })
    }

    /// Whether the service published this heartbeat less than `max_silence` ago.
    ///
    /// Judged by the publish time, not the receive time: a reader that joins late
    /// is handed each service's last heartbeat, which may come from a service
    /// that died long ago. Services beat about once a second, so 3 s is a fair
    /// `max_silence`.
    pub fn is_alive(&self, max_silence: Duration) -> bool {
        self.is_alive_at(SystemTime::now(), max_silence)
    }

    /// [`is_alive`](Self::is_alive) at the time `now`.
    pub fn is_alive_at(&self, now: SystemTime, max_silence: Duration) -> bool {
        // A heartbeat from the future (a clock step) counts as fresh.
        now.duration_since(self.published).map_or(true, |silence| silence <= max_silence)
    }

    /// How long ago (at `now`) the service published this heartbeat.
    pub fn silence_at(&self, now: SystemTime) -> Duration {
        now.duration_since(self.published).unwrap_or(Duration::ZERO)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use outlet_protocol::wire::MAX_HOLES;

    fn msg() -> HolePosesMsg {
        let mut m = HolePosesMsg {
            schema_version: SCHEMA_VERSION,
            hole_count: 2,
            frame_id: 5,
            capture_time_ns: 1_000_000_000,
            published_ns: 1_020_000_000,
            mode: 3,
            status: 1,
            outlier_mask: 0,
            reserved: 0,
            rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            translation_m: [0.0, 0.0, 0.3],
            kinds: [0; MAX_HOLES],
            positions_m: [[0.0; 3]; MAX_HOLES],
            covariances_m2: [[0.0; 9]; MAX_HOLES],
        };
        m.kinds[0] = 1;
        m.kinds[1] = 2;
        m.positions_m[0] = [0.01, 0.02, 0.3];
        m.positions_m[1] = [0.01, 0.04, 0.3];
        m.covariances_m2[1] = [1e-8, 2e-9, 0.0, 2e-9, 4e-8, 0.0, 0.0, 0.0, 9e-8];
        m
    }

    #[test]
    fn face_errors_split_the_covariance_along_the_outlet_normal_and_its_face() {
        // Outlet turned 90 degrees about the camera's y axis: its normal (z) is
        // the camera's -x, its x axis the camera's z.
        let rotation = [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]];
        // 3 mm along camera x (the normal), 0.2 mm along y, 0.1 mm along z.
        let c = [[9e-6, 0.0, 0.0], [0.0, 4e-8, 0.0], [0.0, 0.0, 1e-8]];
        let e = FaceErrors::of(&c, &rotation).expect("finite");
        assert!((e.normal_sigma_m - 3e-3).abs() < 1e-12, "{e:?}");
        assert!((e.in_plane_sigma_m[0] - 1e-4).abs() < 1e-12 && (e.in_plane_sigma_m[1] - 2e-4).abs() < 1e-12);
        assert!((e.in_plane_max_sigma_m - 2e-4).abs() < 1e-12);
        // A correlated in-plane error: the largest direction is the diagonal.
        let c = [[0.0; 3], [0.0, 1e-8, 1e-8], [0.0, 1e-8, 1e-8]];
        assert!((FaceErrors::of(&c, &rotation).expect("finite").in_plane_max_sigma_m - 2e-8f64.sqrt()).abs() < 1e-12);
        assert_eq!(FaceErrors::of(&c, &[[f64::NAN; 3]; 3]), None);
        let p = HolePoses::from_msg(&msg(), time_from_ns(1_030_000_000)).expect("valid");
        let e = p.face_errors(1).expect("hole 1");
        assert!((e.normal_sigma_m - 3e-4).abs() < 1e-12);
        assert_eq!(p.face_errors(2), None);
    }

    #[test]
    fn a_valid_message_becomes_typed_poses() {
        let p = HolePoses::from_msg(&msg(), time_from_ns(1_030_000_000)).expect("valid");
        assert_eq!(p.mode, PoseMode::Plane);
        assert!(p.is_usable());
        assert!(!p.holes[0].outlier);
        assert_eq!(p.holes.len(), 2);
        assert_eq!(p.holes[1].kind, HoleKind::Ground);
        assert_eq!(p.holes[1].covariance_m2[0][1], 2e-9);
        assert!((p.holes[1].std_dev_m()[2] - 3e-4).abs() < 1e-12);
        assert_eq!(p.latency(), Duration::from_millis(20));
        assert_eq!(p.age_at(time_from_ns(1_500_000_000)), Duration::from_millis(500));
        assert_eq!(p.age_at(time_from_ns(0)), Duration::ZERO);
    }

    #[test]
    fn unknown_codes_and_non_finite_poses_are_refused() {
        let bad_mode = HolePosesMsg { mode: 7, ..msg() };
        assert_eq!(
            HolePoses::from_msg(&bad_mode, SystemTime::now()),
            Err(Rejection::UnknownMode { frame_id: 5, code: 7 })
        );
        let mut bad_kind = msg();
        bad_kind.kinds[1] = 9;
        assert!(matches!(
            HolePoses::from_msg(&bad_kind, SystemTime::now()),
            Err(Rejection::UnknownHoleKind { index: 1, code: 9, .. })
        ));
        let mut bad_pose = msg();
        bad_pose.translation_m[2] = f64::INFINITY;
        assert_eq!(HolePoses::from_msg(&bad_pose, SystemTime::now()), Err(Rejection::PoseNotFinite { frame_id: 5 }));
    }

    #[test]
    fn results_without_a_pose_say_why_and_carry_no_holes() {
        let nan = HolePosesMsg {
            status: pose_status::AMBIGUOUS,
            mode: 1,
            hole_count: 0,
            rotation: [f64::NAN; 9],
            translation_m: [f64::NAN; 3],
            ..msg()
        };
        let p = HolePoses::from_msg(&nan, SystemTime::now()).expect("valid");
        assert_eq!(p.status, PoseStatus::Ambiguous);
        assert!(!p.is_usable() && p.holes.is_empty());
        let mismatch = HolePosesMsg { status: pose_status::PLANE_MISMATCH, hole_count: 0, ..msg() };
        assert_eq!(HolePoses::from_msg(&mismatch, SystemTime::now()).map(|p| p.status), Ok(PoseStatus::PlaneMismatch));
        // Holes in a result without a pose, and unknown status codes, are refused.
        assert!(
            HolePoses::from_msg(&HolePosesMsg { status: pose_status::AMBIGUOUS, ..msg() }, SystemTime::now()).is_err()
        );
        assert!(HolePoses::from_msg(&HolePosesMsg { status: 0, ..msg() }, SystemTime::now()).is_err());
        assert!(HolePoses::from_msg(&HolePosesMsg { status: 9, ..msg() }, SystemTime::now()).is_err());
        // The outlier mask marks holes whose pixels were not used.
        let p = HolePoses::from_msg(&HolePosesMsg { outlier_mask: 0b10, ..msg() }, SystemTime::now()).expect("valid");
        assert_eq!(p.holes.iter().map(|h| h.outlier).collect::<Vec<_>>(), vec![false, true]);
        for s in [PoseStatus::Ok, PoseStatus::Ambiguous, PoseStatus::PlaneMismatch] {
            assert_eq!(PoseStatus::from_code(s.code()), Some(s));
        }
    }

    #[test]
    fn heartbeat_latencies_are_none_when_nothing_was_measured() {
        let mut m = HeartbeatMsg::new("pose", 42, 1);
        m.published_ns = 2_000_000_000;
        m.latency_p50_ms = 12.5;
        let h = Heartbeat::from_msg(&m, SystemTime::now()).expect("valid");
        assert_eq!(h.latency_p50, Some(Duration::from_micros(12_500)));
        assert_eq!(h.latency_p99, None);
        assert_eq!(h.last_output, None);
        assert_eq!(h.last_rejection, None);
        assert!(h.is_alive_at(time_from_ns(2_500_000_000), Duration::from_secs(1)));
        assert!(!h.is_alive_at(time_from_ns(3_500_000_000), Duration::from_secs(1)));
        assert!(Heartbeat::from_msg(&HeartbeatMsg { schema_version: 0, ..m }, SystemTime::now()).is_err());
    }
}
