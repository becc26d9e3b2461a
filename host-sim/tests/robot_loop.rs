//! The robot loop on the host: the simulator's two serial lines (LD06 bytes at 10 Hz while the
//! robot drives, poses at 25 Hz on the link) through the firmware's own application, every
//! turn placed at the interpolated pose, checked against the simulator's truth.

use host_sim::firmware::{run, FirmwareArgs};

#[test]
fn simulated_lidar_and_odometry_streams_map_every_turn_at_its_true_pose() {
    let args = FirmwareArgs {
        robot: true,
        host_only: true,
        seed: 3,
        max_scans: Some(40),
        fixed_updates: Some(500),
        ..FirmwareArgs::default()
    };
    let r = run(&args).expect("robot run");
    let rb = r.robot.expect("robot report");
    assert_eq!((rb.turns_sent, rb.turns_mapped), (40, 40));
    assert_eq!(r.device_errors, 0);
    let c = r.counters.expect("counters").lidar;
    // 38 packets a turn; the report after turn 39 comes with the first packet of turn 40.
    assert_eq!(c.packets, 40 * 38 + 1);
    assert_eq!(
        (c.bad_packets, c.packets_without_pose, c.packets_overflowed),
        (0, 0, 0)
    );
    assert!(c.poses as usize >= 40 * 100 / 40, "{c:?}");
    // The poses come every 40 ms of a path that bends at the mission's waypoints: the
    // interpolated turn pose stays within half a 5 cm cell of the truth.
    assert!(rb.max_position_error_mm < 25.0, "{rb:?}");
    let done = r.done.expect("Done");
    assert_eq!(done.scans, 40);
}
