//! `cac meshes generate`: writes the built-in default objects as OBJ + MTL + PNG;
//! `cac meshes hostile`: writes the seeded hostile meshes (`cac::scene::hostile`).

use anyhow::Result;
use cac::scene::{generate, hostile, obj_write};
use std::path::PathBuf;

#[derive(clap::Subcommand, Debug)]
pub enum Cmd {
    /// Generate the default objects (pickup, jeep, barrel, container) into a folder.
    Generate {
        #[arg(long, default_value = "meshes")]
        out: PathBuf,
    },
    /// Write the hostile meshes (tiled UVs, 1 mm to 1 km, NaN vertices, 1 M triangles, 10 k
    /// parts, missing files, ...) to try a pipeline on; each says what cac must do with it.
    Hostile {
        #[arg(long, default_value = "hostile")]
        out: PathBuf,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Only these cases (comma-separated; default: all).
        #[arg(long, value_delimiter = ',')]
        cases: Vec<String>,
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
        Cmd::Hostile { out, seed, cases } => {
            let names: Vec<String> = if cases.is_empty() {
                hostile::CASES.iter().map(|s| s.to_string()).collect()
            } else {
                cases
            };
            for n in names {
                let c = hostile::write_case(&out, &n, seed)?;
                println!(
                    "wrote {} ({} triangles): {}",
                    c.mesh.display(),
                    c.triangles,
                    match c.expect {
                        hostile::Expect::Loads => "must load".to_string(),
                        hostile::Expect::Refused(why) => format!("must be refused ({why})"),
                    }
                );
            }
            Ok(())
        }
    }
}
