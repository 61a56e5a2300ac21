//! `cmsckf-frontend`: camera images in, feature tracks out on the daemon's
//! socket. Why it exists: the daemon fuses feature tracks, and a drone with
//! a real camera needs something that makes them. Pure Rust, no system
//! libraries, so the README's two commands still set everything up.
//!
//! - [`image`]: grey images and pyramids, bilinear sampling;
//! - [`detect`]: Shi–Tomasi corners over a grid, apart from tracked ones;
//! - [`klt`]: pyramidal Lucas–Kanade with the forward–backward check;
//! - [`affine`]: each track held to its first window by an affine warp;
//! - [`ransac`]: outliers off the epipolar geometry (8-point, Sampson);
//! - [`tracker`]: the per-frame pipeline with stable landmark ids;
//! - [`reid`]: old landmarks re-identified by steered BRIEF ([`brief`]) on
//!   keyframes, checked against their first look ([`landmark_windows`]);
//! - [`source`]: frames from a EuRoC/ASL folder or a camera socket, and
//!   their stamps; [`euroc`]: the dataset layout;
//! - [`run`]: the loop from a source to the daemon's socket; [`output`]:
//!   the socket's lines;
//! - [`synthetic`]: images with known motion, for tests and benchmarks;
//! - `v4l2` (cargo feature `v4l2`): a Video4Linux2 camera as a source.

// Names carry their frames (`R_W_C`, `p_C_in_W`), as everywhere here.
#![allow(non_snake_case)]

pub mod affine;
pub mod brief;
pub mod detect;
pub mod euroc;
pub mod image;
pub mod klt;
pub mod landmark_windows;
pub mod output;
pub mod ransac;
pub mod reid;
pub mod run;
pub mod source;
pub mod synthetic;
pub mod tracker;
#[cfg(feature = "v4l2")]
pub mod v4l2;
