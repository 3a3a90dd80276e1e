//! The C ABI called from Rust: results arrive intact, NULLs and bad input give
//! error codes and a last-error text, never a crash.

mod common;

use common::{POSITIONS_M, PoseService, poses, unique_domain};
use outlet_client_c::*;
use outlet_protocol::wire::SCHEMA_VERSION;
use std::ffi::{CString, c_char};
use std::ptr;

fn last_error() -> String {
    // SAFETY: NULL with length 0 only asks for the length.
    let length = unsafe { outlet_last_error(ptr::null_mut(), 0) };
    let mut buf = vec![1 as c_char; length + 1];
    // SAFETY: buf has buf.len() writable bytes.
    assert_eq!(unsafe { outlet_last_error(buf.as_mut_ptr(), buf.len()) }, length);
    assert_eq!(buf[length], 0, "NUL-terminated");
    String::from_utf8(buf[..length].iter().map(|&c| c as u8).collect()).expect("UTF-8")
}

#[test]
fn results_cross_the_abi_intact() {
    let domain = unique_domain();
    let name = CString::new(domain.0.clone()).expect("no NUL");
    // SAFETY: a NUL-terminated string valid for the call.
    let client = unsafe { outlet_client_connect(name.as_ptr()) };
    assert!(!client.is_null(), "{}", last_error());
    let pose = PoseService::open(&domain);

    // SAFETY: OutletHolePoses is plain data; all zeros is a valid value.
    let mut out: OutletHolePoses = unsafe { std::mem::zeroed() };
    // SAFETY: a live client from this thread, and a writable out.
    assert_eq!(unsafe { outlet_client_latest(client, &mut out) }, OUTLET_NONE);
    assert_eq!(unsafe { outlet_client_wait_next(client, 50, &mut out) }, OUTLET_NONE);
    // SAFETY: as above.
    assert_eq!(unsafe { outlet_client_last_result_ns(client) }, 0);

    let sent = poses(42);
    pose.send(sent);
    // SAFETY: as above.
    assert_eq!(unsafe { outlet_client_wait_next(client, 5000, &mut out) }, OUTLET_OK);
    assert_eq!(out.frame_id, 42);
    assert_eq!(out.capture_time_ns, sent.capture_time_ns);
    assert_eq!(out.published_ns, sent.published_ns);
    assert!(out.received_ns >= out.published_ns);
    assert_eq!(out.mode, OUTLET_MODE_PLANE);
    assert_eq!(out.hole_count, 3);
    assert_eq!(out.rotation, sent.rotation);
    assert_eq!(out.translation_m, sent.translation_m);
    let kinds: Vec<u32> = out.holes[..3].iter().map(|h| h.kind).collect();
    assert_eq!(kinds, [OUTLET_HOLE_POWER, OUTLET_HOLE_POWER, OUTLET_HOLE_GROUND]);
    for (hole, position) in out.holes.iter().zip(POSITIONS_M) {
        assert_eq!(hole.position_m, position);
    }
    assert_eq!(out.holes[0].covariance_m2, sent.covariances_m2[0]);
    // The outlet faces the camera (its normal the camera's -z): 0.2 mm along the
    // normal, 0.1 mm along each face axis, 0.11 mm at most (the correlation).
    let h = &out.holes[0];
    assert!((h.normal_sigma_m - 2e-4).abs() < 1e-12, "{h:?}");
    assert!(h.in_plane_sigma_m.iter().all(|s| (s - 1e-4).abs() < 1e-12), "{h:?}");
    assert!((h.in_plane_max_sigma_m - 1.2e-8f64.sqrt()).abs() < 1e-12, "{h:?}");
    assert_eq!(out.holes[3].kind, 0);
    // SAFETY: as above.
    assert_eq!(unsafe { outlet_client_last_result_ns(client) }, out.received_ns);

    let mut latest = out;
    latest.frame_id = 0;
    // SAFETY: as above.
    assert_eq!(unsafe { outlet_client_latest(client, &mut latest) }, OUTLET_OK);
    assert_eq!(latest, out);

    pose.send(outlet_protocol::wire::HolePosesMsg { schema_version: SCHEMA_VERSION + 1, ..poses(43) });
    // SAFETY: as above.
    assert_eq!(unsafe { outlet_client_wait_next(client, 100, &mut out) }, OUTLET_NONE);
    // SAFETY: as above.
    assert_eq!(unsafe { outlet_client_rejected(client) }, 1);

    // SAFETY: freed once, not used after.
    unsafe { outlet_client_free(client) };
}

#[test]
fn null_arguments_give_error_codes_not_crashes() {
    // SAFETY: every function is documented to accept NULL.
    unsafe {
        assert_eq!(outlet_client_wait_next(ptr::null_mut(), 0, ptr::null_mut()), OUTLET_ERR_NULL_ARGUMENT);
        assert!(last_error().contains("client is NULL"));
        assert_eq!(outlet_client_latest(ptr::null_mut(), ptr::null_mut()), OUTLET_ERR_NULL_ARGUMENT);
        assert_eq!(outlet_client_last_result_ns(ptr::null()), 0);
        assert_eq!(outlet_client_rejected(ptr::null()), 0);
        outlet_client_free(ptr::null_mut());
        assert!(outlet_last_error(ptr::null_mut(), 0) > 0);
    }
    let domain = unique_domain();
    let name = CString::new(domain.0.clone()).expect("no NUL");
    // SAFETY: a NUL-terminated string valid for the call.
    let client = unsafe { outlet_client_connect(name.as_ptr()) };
    assert!(!client.is_null(), "{}", last_error());
    // SAFETY: a live client; `out` NULL is documented to be refused.
    assert_eq!(unsafe { outlet_client_wait_next(client, 0, ptr::null_mut()) }, OUTLET_ERR_NULL_ARGUMENT);
    assert!(last_error().contains("out is NULL"));
    // SAFETY: freed once.
    unsafe { outlet_client_free(client) };
}

#[test]
fn a_bad_domain_gives_null_and_says_why() {
    let name = CString::new("No/Such/Domain").expect("no NUL");
    // SAFETY: a NUL-terminated string valid for the call.
    let client = unsafe { outlet_client_connect(name.as_ptr()) };
    assert!(client.is_null());
    assert!(last_error().contains("No/Such/Domain"), "{}", last_error());
}

#[test]
fn last_error_is_cut_to_the_buffer_at_a_character_and_nul_terminated() {
    let name = CString::new("é".repeat(40)).expect("no NUL");
    // SAFETY: a NUL-terminated string valid for the call.
    assert!(unsafe { outlet_client_connect(name.as_ptr()) }.is_null());
    let full = last_error();
    let first = full.find('é').expect("the domain is in the message");
    // A buffer that ends in the middle of the first 'é' (2 bytes): the text stops before it.
    let mut buf = vec![1 as c_char; first + 2];
    // SAFETY: buf has buf.len() writable bytes.
    let length = unsafe { outlet_last_error(buf.as_mut_ptr(), buf.len()) };
    assert_eq!(length, full.len());
    let end = buf.iter().position(|&c| c == 0).expect("NUL-terminated");
    let bytes: Vec<u8> = buf[..end].iter().map(|&c| c as u8).collect();
    assert_eq!(std::str::from_utf8(&bytes), Ok(&full[..first]));
}
