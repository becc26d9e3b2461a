//! The serial device of the robot's link.

use std::path::Path;
use std::time::Duration;

use anyhow::bail;

/// Opens a serial device for the link (raw 8N1, `timeout` per read/write). A pseudo-terminal
/// that refuses the baud rate is opened without setting it, with a warning on stderr.
pub fn open_port(
    path: &Path,
    baud: u32,
    timeout: Duration,
) -> anyhow::Result<Box<dyn serialport::SerialPort>> {
    let name = path.display().to_string();
    match std::fs::metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{name}: no such file or device")
        }
        Err(e) => bail!("{name}: {e}"),
        Ok(m) if m.is_dir() => bail!("{name}: is a directory, not a serial device"),
        Ok(_) => {}
    }
    let Some(path_str) = path.to_str() else {
        bail!("{name}: device path is not UTF-8");
    };
    let open = |baud: u32| serialport::new(path_str, baud).timeout(timeout).open();
    let describe = |e: &serialport::Error| -> String {
        use serialport::ErrorKind as K;
        match e.kind() {
            K::NoDevice => format!("{name}: busy or gone ({e})"),
            K::Io(std::io::ErrorKind::NotFound) => format!("{name}: no such file or device"),
            K::Io(std::io::ErrorKind::PermissionDenied) => format!(
                "{name}: permission denied (is your user in the device's group, e.g. dialout?)"
            ),
            _ => format!("{name}: cannot open as a serial port: {e}"),
        }
    };
    match open(baud) {
        Ok(p) => Ok(p),
        Err(e)
            if matches!(
                e.kind(),
                serialport::ErrorKind::NoDevice
                    | serialport::ErrorKind::Io(
                        std::io::ErrorKind::NotFound | std::io::ErrorKind::PermissionDenied
                    )
            ) =>
        {
            bail!("{}", describe(&e))
        }
        Err(e) => match open(0) {
            Ok(p) => {
                eprintln!(
                    "warning: {name}: cannot set {baud} baud ({e}); using the device's own speed"
                );
                Ok(p)
            }
            Err(_) => bail!("{}", describe(&e)),
        },
    }
}

/// An I/O error that only means "nothing yet, try again" on a serial port.
pub(super) fn transient(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::Interrupted
    )
}
