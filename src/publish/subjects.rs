//! The broker's names (docs/API.md, "Through a NATS broker"): one camera's sets on
//! `vemlight.v1.<camera>.lights.<n>`, its health on `vemlight.v1.<camera>.status`, and the
//! JetStream stream `vemlight_<camera>` that keeps the last message of each. Publisher and
//! viewers share these, so that they cannot disagree.

/// The first tokens of every subject.
pub const PREFIX: &str = "vemlight.v1";

/// The wildcard a viewer subscribes to to list the cameras on a broker.
pub const ALL_STATUS: &str = "vemlight.v1.*.status";

/// Longest camera name (a subject token and part of a stream name).
pub const CAMERA_MAX_LEN: usize = 64;

/// `vemlight.v1.<camera>.lights.<n>`.
pub fn lights(camera: &str, n: usize) -> String {
    format!("{PREFIX}.{camera}.lights.{n}")
}

/// `vemlight.v1.<camera>.status`.
pub fn status(camera: &str) -> String {
    format!("{PREFIX}.{camera}.status")
}

/// `vemlight.v1.<camera>.>`: everything one camera publishes (the stream's subjects).
pub fn camera_all(camera: &str) -> String {
    format!("{PREFIX}.{camera}.>")
}

/// The JetStream stream holding `camera`'s last values: `vemlight_<camera>`.
pub fn stream_name(camera: &str) -> String {
    format!("vemlight_{camera}")
}

/// The camera a status or lights subject belongs to.
pub fn camera_of(subject: &str) -> Option<&str> {
    let rest = subject.strip_prefix(PREFIX)?.strip_prefix('.')?;
    let (camera, _) = rest.split_once('.')?;
    check_camera(camera).ok().map(|()| camera)
}

/// A camera name is one subject token that is also valid in a stream name: 1 to 64 of
/// `A–Z a–z 0–9 _ -`.
pub fn check_camera(name: &str) -> Result<(), String> {
    if name.is_empty() || name.len() > CAMERA_MAX_LEN {
        return Err(format!(
            "a camera name has 1 to {CAMERA_MAX_LEN} characters, got {}",
            name.len()
        ));
    }
    match name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '-'))
    {
        Some(c) => Err(format!(
            "camera name '{name}' has '{c}': use letters, digits, '_' and '-' (it is a NATS subject token)"
        )),
        None => Ok(()),
    }
}

/// `name` made into a camera name: every other character becomes `_`, cut to 64; `camera` when
/// nothing is left. For the default, the host name (`cam-01.site.local` → `cam-01_site_local`).
pub fn sanitize_camera(name: &str) -> String {
    let s: String = name
        .trim()
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .take(CAMERA_MAX_LEN)
        .collect();
    if s.is_empty() { "camera".into() } else { s }
}

/// This machine's host name as a camera name (`camera` when it cannot be read).
pub fn default_camera() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_default();
    sanitize_camera(&host)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subjects_and_names() {
        assert_eq!(lights("roof", 16), "vemlight.v1.roof.lights.16");
        assert_eq!(status("roof"), "vemlight.v1.roof.status");
        assert_eq!(camera_all("roof"), "vemlight.v1.roof.>");
        assert_eq!(stream_name("roof"), "vemlight_roof");
        assert_eq!(camera_of("vemlight.v1.roof.status"), Some("roof"));
        assert_eq!(camera_of("vemlight.v1.roof.lights.8"), Some("roof"));
        assert_eq!(camera_of("other.v1.roof.status"), None);
        assert_eq!(camera_of("vemlight.v1.status"), None);
    }

    #[test]
    fn camera_names() {
        assert!(check_camera("cam-01_a").is_ok());
        for bad in ["", "a.b", "a b", "a*", "a>", "é"] {
            assert!(check_camera(bad).is_err(), "{bad:?}");
        }
        assert!(check_camera(&"x".repeat(65)).is_err());
        assert_eq!(sanitize_camera("cam-01.site.local"), "cam-01_site_local");
        assert_eq!(sanitize_camera("  \n"), "camera");
        assert_eq!(sanitize_camera(&"y".repeat(100)).len(), CAMERA_MAX_LEN);
        for name in ["cam-01.site.local", "a b*c>", "ü"] {
            assert!(check_camera(&sanitize_camera(name)).is_ok());
        }
    }
}
