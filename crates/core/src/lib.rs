//! The shared floor of cac's crates: files written atomically ([`io`]), the memory budget
//! ([`memory`]), and tables, plots, HTML and drawn labels ([`report`]).

pub mod io;
pub mod memory;
pub mod report;
