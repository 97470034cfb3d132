//! `cac demo`: the main job on the embedded defaults (`cac::study::demo::DemoJob`: a short
//! attack against NanoDet, scored before and after on protocol views with CenterNet as the
//! transfer model); parses, runs it, prints its table.

use super::device;
use super::flags::eval::DemoFlags;
use anyhow::Result;
use cac::study::demo::DemoJob;

pub fn run(a: DemoFlags) -> Result<()> {
    let a = DemoJob::from(a);
    let o = a.run(&device::inference())?;
    print!("{}", o.table);
    println!(
        "\nwrote {} (atlases, before/after view sheets with each detector's boxes, summary.json, \
         run/) in {:.0} s",
        a.out.display(),
        o.seconds
    );
    Ok(())
}
