//! `cac bench export`'s flags, mapped onto [`ExportBench`].

use cac::bench::export::ExportBench;
use cac::export::Scale;
use std::path::PathBuf;

/// `ExportBench`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct ExportBenchFlags {
    /// The object (file or default name).
    #[arg(long, default_value = "jeep")]
    pub mesh: PathBuf,
    /// The texture; default: a synthetic camouflage at --res ([`synthetic_camouflage`]).
    #[arg(long)]
    pub texture: Option<PathBuf>,
    /// Resolution of the synthetic camouflage.
    #[arg(long, default_value_t = ExportBench::default().res)]
    pub res: usize,
    #[arg(long, default_value = "1:24")]
    pub scale: Scale,
    /// Edge limits in texels to try.
    #[arg(long, value_delimiter = ',', default_value = "16,8,4,2,1,0.5")]
    pub texels: Vec<f32>,
    /// Edge limits in mm to try (texel limit off), e.g. 2,1,0.5.
    #[arg(long, value_delimiter = ',')]
    pub mm: Vec<f32>,
    /// Random surface samples for the error.
    #[arg(long, default_value_t = ExportBench::default().samples)]
    pub samples: usize,
    /// Also solidify at these grid spacings (mm), e.g. 1.6,0.8,0.4,0.2: error against time.
    #[arg(long, value_delimiter = ',')]
    pub solid_voxels: Vec<f32>,
    /// Subdivide the mesh to at least this many triangles before solidifying (0: as loaded).
    #[arg(long, default_value_t = ExportBench::default().solid_input_triangles)]
    pub solid_input_triangles: usize,
}

impl From<ExportBenchFlags> for cac::bench::export::ExportBench {
    fn from(f: ExportBenchFlags) -> Self {
        ExportBench {
            mesh: f.mesh,
            texture: f.texture,
            res: f.res,
            scale: f.scale,
            texels: f.texels,
            mm: f.mm,
            samples: f.samples,
            solid_voxels: f.solid_voxels,
            solid_input_triangles: f.solid_input_triangles,
        }
    }
}
