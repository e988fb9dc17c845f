//! One module per subcommand. Argument structs live beside the code that uses them.

pub mod bench;
pub mod calibrate;
pub mod data;
pub mod eval;
pub mod export;
pub mod optimize;
pub mod posterior;
pub mod scene;
pub mod seal;
pub mod simulate;
pub mod train;
