//! `cac meshes generate`: writes the built-in default objects as OBJ + MTL + PNG.

use anyhow::Result;
use cac::scene::{generate, obj_write};
use std::path::PathBuf;

#[derive(clap::Subcommand, Debug)]
pub enum Cmd {
    /// Generate the default objects (pickup, jeep, barrel, container) into a folder.
    Generate {
        #[arg(long, default_value = "meshes")]
        out: PathBuf,
    },
}

pub fn run(c: Cmd) -> Result<()> {
    match c {
        Cmd::Generate { out } => {
            for name in generate::DEFAULT_OBJECTS {
                let mut s = generate::by_name(name).expect("built-in object");
                s.normalise(0.0, None);
                let dir = out.join(name);
                obj_write::write_obj(&s, &dir, name)?;
                println!(
                    "wrote {} ({} triangles, {:.2} m long)",
                    dir.join(format!("{name}.obj")).display(),
                    s.triangles.len(),
                    s.length()
                );
            }
            Ok(())
        }
    }
}
