//! `cac camera`: check a V4L2 camera as a capture session will use it. Parse →
//! `cac::physical::camera_check::CameraCheck` → print.

use super::flags::physical::CameraCheckFlags;
use anyhow::Result;
use cac::physical::camera_check::CameraCheck;

pub fn run(job: CameraCheckFlags) -> Result<()> {
    let job = CameraCheck::from(job);
    let r = job.run()?;
    println!("{}", r.camera);
    if let Some(s) = &r.settings {
        let fps = |v: Option<f64>| v.map_or("-".to_string(), |f| format!("{f}"));
        println!(
            "{} {}x{}; frames/s asked {}, reported {}, measured {}",
            s.format,
            s.width,
            s.height,
            fps(s.fps_asked),
            fps(s.fps_reported),
            fps(s.fps_measured)
        );
        for c in &s.controls {
            match c.value {
                Some(v) => println!(
                    "{} locked at {v}{}",
                    c.name,
                    if c.auto_off { " (auto off)" } else { "" }
                ),
                None => println!("{}: the camera has no such control", c.name),
            }
        }
    }
    for f in &r.frames {
        println!("{}: {}", f.file, f.origin);
        for e in &f.events {
            println!("  {e}");
        }
    }
    println!(
        "wrote {} frames and camera.json into {}",
        r.frames.len(),
        job.out.display()
    );
    Ok(())
}
