//! The example scenes of `config/scenes/`, embedded in the binary, and the files they name.

use crate::{Error, Result};

/// The example scenes of `config/scenes/`, embedded in the binary: (name, scene JSON). Those with
/// a `camera` are frame scenes (`POST /v1/render`, frame jobs); the others are cloud sections
/// (`skybake clouds`).
pub const EXAMPLE_SCENES: &[(&str, &str)] = &[
    (
        "automaton-field",
        include_str!("../../../../config/scenes/automaton-field.json"),
    ),
    (
        "cumulus-fractal",
        include_str!("../../../../config/scenes/cumulus-fractal.json"),
    ),
    (
        "cumulus-frame",
        include_str!("../../../../config/scenes/cumulus-frame.json"),
    ),
    (
        "cumulus-metaballs",
        include_str!("../../../../config/scenes/cumulus-metaballs.json"),
    ),
    (
        "satellite-field",
        include_str!("../../../../config/scenes/satellite-field.json"),
    ),
    (
        "sphere-cloud",
        include_str!("../../../../config/scenes/sphere-cloud.json"),
    ),
    (
        "validation-frame",
        include_str!("../../../../config/scenes/validation-frame.json"),
    ),
    (
        "vdb-cloud",
        include_str!("../../../../config/scenes/vdb-cloud.json"),
    ),
];

/// Files the example scenes name, embedded with them: (name as written in the scene, bytes).
const EXAMPLE_FILES: &[(&str, &[u8])] = &[
    (
        "satellite-field.png",
        include_bytes!("../../../../config/scenes/satellite-field.png"),
    ),
    (
        "vdb-cloud.vdb",
        include_bytes!("../../../../config/scenes/vdb-cloud.vdb"),
    ),
];

/// The example scene `name`'s JSON, if there is one.
pub fn example_scene(name: &str) -> Option<&'static str> {
    EXAMPLE_SCENES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, json)| *json)
}

/// The loader of scenes that arrive over the network (service, jobs): a scene may name only the
/// files of the example scenes (embedded), never a file of the machine it runs on.
pub fn example_file(name: &str) -> Result<Vec<u8>> {
    EXAMPLE_FILES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, bytes)| bytes.to_vec())
        .ok_or_else(|| {
            let known: Vec<&str> = EXAMPLE_FILES.iter().map(|(n, _)| *n).collect();
            Error::invalid(
                "path",
                format!(
                    "'{name}': a scene sent to the service can name only the example scenes' files ({}); send other clouds as a grid through skybake render",
                    known.join(", ")
                ),
            )
        })
}
