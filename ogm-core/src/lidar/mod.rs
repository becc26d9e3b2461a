//! Scans from real sensors: the LD06 and RPLIDAR A1/A2 wire formats (sans-IO parsers and
//! blocking readers over `embedded_io::Read`), the robot's receive link (lidar bytes and host
//! frames on one UART), lidar turns assembled and deskewed with poses that arrive on their own
//! (the one way scans reach the session: [`source`] says why).

pub mod encode;
pub mod ld06;
pub mod link;
pub mod pose_track;
pub mod rplidar;
pub mod source;
pub mod turn;
