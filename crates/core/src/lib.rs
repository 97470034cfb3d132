//! The shared floor of cac's crates: the memory budget ([`memory`]), colour ([`colour`]: sRGB,
//! CIELAB, ΔE2000), files written atomically ([`io`]), tables, plots, HTML and drawn labels
//! ([`report`]), printer models ([`printer`]: what a printer makes of a requested colour), and
//! settings with named values ([`choice`]).

pub mod choice;
pub mod colour;
pub mod io;
pub mod memory;
pub mod printer;
pub mod report;
