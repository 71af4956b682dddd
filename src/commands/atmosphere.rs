//! `skybake atmosphere`: the built-in atmospheres, as JSON to start your own from.

use skybake_physics::atmosphere::presets;
use skybake_physics::Error;

use crate::error::Result;
use crate::io::print_json;

/// `--print PRESET` prints one preset; `--list` names them all.
pub fn atmosphere(print: Option<&str>, list: bool) -> Result<()> {
    if let Some(name) = print {
        print_json(&presets::preset(name)?)
    } else if list {
        for name in presets::preset_names() {
            println!("{name}");
        }
        Ok(())
    } else {
        Err(Error::invalid("atmosphere", "use --print PRESET or --list").into())
    }
}
