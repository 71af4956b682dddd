//! Frame entries of a job: a scene rendered once per value of a sweep, for a
//! sun sweep (elevations, azimuths or times of day) or an automaton animation (cloud frames at
//! successive automaton steps).
//!
//! ```json
//! {"frames": [{"example": "cumulus-frame", "method": "fast",
//!              "sweep": {"sun_elevation_deg": {"from": 5, "to": 85, "step": 10}}},
//!             {"scene": {…a frame scene…}, "sweep": {"frame_time_steps": [100, 101, 102]}}]}
//! ```
//!
//! Each entry takes exactly one of `scene` (inline frame scene JSON) or `example` (the name of an
//! embedded example scene, `GET /v1/scenes`), an optional `method` (`fast`, default, or
//! `reference`), an optional `max_rel_error` (the target relative error of every frame of the
//! entry, as `POST /v1/render?max_rel_error=E`: [`FrameRequest::with_max_rel_error`]'s rule, errors
//! named `frames[i].max_rel_error`) and an optional `sweep`. Sweep axes (values as a list or
//! `{from, to, step}`) combine like a grid's, in alphabetical order, the last varying fastest:
//!
//! - `sun_elevation_deg`, `sun_azimuth_deg`: replace the scene sun's elevation / azimuth (a sun
//!   given by elevation and azimuth, or a collimated one);
//! - `time`: RFC 3339 times replacing the time of a sun given by place and time;
//! - `frame_time_steps`: the automaton frame of a cloud whose source is an `automaton`;
//! - `view_orbit_deg`: turns the camera (its position and `up`) about the vertical through its
//!   `look_at_m` by this angle, towards increasing azimuth (from +y towards +x): a fly-around;
//! - `view_distance_m`: puts the camera at this distance (> 0) from its `look_at_m`, on the line
//!   it looks along: an approach. With both, the distance applies before the turn.
//!
//! The camera axes sort after the sun's, so they vary fastest: the frames of one sun follow each
//! other and share the lit cloud (`skybake_product::frame::FrameReuse`).
//!
//! Item `k` of an entry is the scene with the `k`-th combination applied; its errors are named
//! `frames[i][k].<field>`.

use super::JobError;
use crate::Error;
use serde_json::{Map, Value};
use skybake_product::frame::{example_scene, FrameRequest};
use skybake_render::Method;

/// Axes a frame entry can sweep.
pub const FRAME_AXES: &[&str] = &[
    "frame_time_steps",
    "sun_azimuth_deg",
    "sun_elevation_deg",
    "time",
    "view_distance_m",
    "view_orbit_deg",
];

/// Turns a sweep member (field name, JSON value, most values) into its values.
pub type AxisValuesFn = dyn Fn(&str, &Value, usize) -> Result<Vec<String>, Error>;

/// Members a frame entry takes.
const ENTRY_MEMBERS: &[&str] = &["scene", "example", "method", "max_rel_error", "sweep"];

/// One `frames[i]` entry: the base scene, the method, the target error and the sweep.
#[derive(Debug, Clone)]
pub struct FrameSweep {
    scene: Value,
    method: Method,
    /// The entry's `max_rel_error` as given (a number's JSON text, or the string), checked by
    /// [`FrameRequest::with_max_rel_error`] for every frame.
    max_rel_error: Option<String>,
    /// The entry's prefix (`frames[0].`), naming errors of the entry's own members.
    prefix: String,
    /// (axis, values), last varies fastest.
    axes: Vec<(String, Vec<String>)>,
    len: usize,
}

impl FrameSweep {
    /// Parses `frames[i]` (named by `prefix`, e.g. `frames[0].`), refusing more than `max_items`
    /// frames before generating any. `axis_values` turns a sweep member into its values.
    pub fn parse(
        obj: &Map<String, Value>,
        prefix: &str,
        max_items: usize,
        axis_values: &AxisValuesFn,
    ) -> Result<Self, JobError> {
        if let Some(k) = obj.keys().find(|k| !ENTRY_MEMBERS.contains(&k.as_str())) {
            return Err(JobError::Unknown(vec![format!("{prefix}{k}")]));
        }
        let scene = match (obj.get("scene"), obj.get("example")) {
            (Some(scene @ Value::Object(_)), None) => scene.clone(),
            (None, Some(Value::String(name))) => {
                let text = example_scene(name).ok_or_else(|| {
                    Error::invalid(
                        &format!("{prefix}example"),
                        format!("no example scene '{name}' (see GET /v1/scenes)"),
                    )
                })?;
                serde_json::from_str(text).map_err(|e| Error::internal("example scene", e))?
            }
            (Some(_), None) => {
                return Err(
                    Error::invalid(&format!("{prefix}scene"), "must be a JSON object").into(),
                )
            }
            (None, Some(_)) => {
                return Err(Error::invalid(&format!("{prefix}example"), "must be a name").into())
            }
            _ => {
                return Err(Error::invalid(
                    &format!("{prefix}scene"),
                    "give exactly one of scene (inline frame scene) or example (a scene name)",
                )
                .into())
            }
        };
        let method = match obj.get("method") {
            None => Method::Fast,
            Some(Value::String(m)) => Method::parse(m).map_err(|e| e.prefixed(prefix))?,
            Some(_) => {
                return Err(Error::invalid(
                    &format!("{prefix}method"),
                    "must be 'fast' or 'reference'",
                )
                .into())
            }
        };
        // A number, or a string holding one, as the parameter table's members of product items.
        let max_rel_error = match obj.get("max_rel_error") {
            None | Some(Value::Null) => None,
            Some(Value::Number(n)) => Some(n.to_string()),
            Some(Value::String(s)) => Some(s.clone()),
            Some(_) => {
                return Err(Error::invalid(
                    &format!("{prefix}max_rel_error"),
                    "must be a number (the target relative error, e.g. 0.3)",
                )
                .into())
            }
        };
        let mut axes = Vec::new();
        let mut len: usize = 1;
        match obj.get("sweep") {
            None | Some(Value::Null) => {}
            Some(Value::Object(sweep)) => {
                for (name, values) in sweep {
                    let field = format!("{prefix}sweep.{name}");
                    if !FRAME_AXES.contains(&name.as_str()) {
                        return Err(JobError::Unknown(vec![field]));
                    }
                    let vals = axis_values(&field, values, max_items)?;
                    len = len
                        .checked_mul(vals.len())
                        .filter(|&n| n <= max_items)
                        .ok_or_else(|| {
                            Error::too_large(
                                "products",
                                format!("{field}: more than {max_items} frames"),
                                max_items,
                            )
                        })?;
                    axes.push((name.clone(), vals));
                }
            }
            Some(_) => {
                return Err(
                    Error::invalid(&format!("{prefix}sweep"), "must be an object of axes").into(),
                )
            }
        }
        // The target is checked with each item's request (`JobSpec::validate` checks every item
        // before a job is accepted), by the render request's own rule.
        Ok(Self {
            scene,
            method,
            max_rel_error,
            prefix: prefix.to_string(),
            axes,
            len,
        })
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Frame `k`'s request (errors named with `prefix`, e.g. `frames[0][k].`).
    pub fn request(&self, k: usize, prefix: &str) -> Result<FrameRequest, Error> {
        let mut scene = self.scene.clone();
        let mut rest = k;
        for (name, values) in self.axes.iter().rev() {
            let v = &values[rest % values.len()];
            rest /= values.len();
            apply(&mut scene, name, v).map_err(|e| e.prefixed(prefix))?;
        }
        let request =
            FrameRequest::from_value(&scene, self.method).map_err(|e| e.prefixed(prefix))?;
        self.with_target(request)
    }

    /// `request` with the entry's target (errors named with the entry's prefix,
    /// `frames[0].max_rel_error`).
    fn with_target(&self, request: FrameRequest) -> Result<FrameRequest, Error> {
        request
            .with_max_rel_error(self.max_rel_error.as_deref())
            .map_err(|e| e.prefixed(&self.prefix))
    }
}

/// A sweep value as a JSON number; whole numbers stay integers, so a swept scene has the cache key
/// of the same scene written by hand.
fn number(axis: &str, v: &str) -> Result<Value, Error> {
    if let Ok(i) = v.trim().parse::<i64>() {
        return Ok(Value::from(i));
    }
    v.trim()
        .parse::<f64>()
        .ok()
        .filter(|x| x.is_finite())
        .and_then(serde_json::Number::from_f64)
        .map(Value::Number)
        .ok_or_else(|| Error::invalid(axis, format!("'{v}' is not a finite number")))
}

/// Puts sweep value `v` of `axis` into `scene`.
fn apply(scene: &mut Value, axis: &str, v: &str) -> Result<(), Error> {
    let sun = scene.get_mut("sun").and_then(Value::as_object_mut);
    match axis {
        "sun_elevation_deg" | "sun_azimuth_deg" => {
            let member = &axis[4..];
            let sun = sun.ok_or_else(|| Error::invalid("sun", "missing (required)"))?;
            let target = if let Some(Value::Object(c)) = sun.get_mut("collimated") {
                c
            } else if sun.contains_key("elevation_deg") {
                sun
            } else {
                return Err(Error::invalid(
                    axis,
                    "sweeps a sun given by elevation_deg and azimuth_deg (or collimated), not by place and time (sweep time instead)",
                ));
            };
            target.insert(member.to_string(), number(axis, v)?);
        }
        "time" => {
            let sun = sun.ok_or_else(|| Error::invalid("sun", "missing (required)"))?;
            if !sun.contains_key("time") {
                return Err(Error::invalid(
                    axis,
                    "sweeps a sun given by latitude_deg, longitude_deg and time (sweep sun_elevation_deg instead)",
                ));
            }
            sun.insert("time".into(), Value::String(v.to_string()));
        }
        "frame_time_steps" => {
            let source = scene
                .pointer_mut("/cloud/source")
                .and_then(Value::as_object_mut)
                .filter(|s| s.get("type").and_then(Value::as_str) == Some("automaton"))
                .ok_or_else(|| {
                    Error::invalid(axis, "sweeps a cloud whose source is an automaton")
                })?;
            source.insert("frame_time_steps".into(), number(axis, v)?);
        }
        "view_orbit_deg" | "view_distance_m" => camera_path(scene, axis, v)?,
        _ => return Err(Error::invalid(axis, "not a frame sweep axis")),
    }
    Ok(())
}

/// A number as JSON; whole numbers as integers (a camera turned by 0° keeps its scene's key).
fn json_number(x: f64) -> Value {
    if x.fract() == 0.0 && x.abs() < 9.0e15 {
        Value::from(x as i64)
    } else {
        serde_json::Number::from_f64(x).map_or(Value::Null, Value::Number)
    }
}

/// The camera member `name` (3 numbers), named `camera.<name>` in errors.
fn camera_vector(camera: &Map<String, Value>, name: &str) -> Result<[f64; 3], Error> {
    let field = format!("camera.{name}");
    let values = camera
        .get(name)
        .and_then(Value::as_array)
        .filter(|a| a.len() == 3)
        .ok_or_else(|| Error::invalid(&field, "must be 3 numbers"))?;
    let mut out = [0.0; 3];
    for (o, v) in out.iter_mut().zip(values) {
        *o = v
            .as_f64()
            .filter(|x| x.is_finite())
            .ok_or_else(|| Error::invalid(&field, "must be 3 finite numbers"))?;
    }
    Ok(out)
}

/// Applies a camera-path axis (`view_orbit_deg`, `view_distance_m`) to the scene's camera.
fn camera_path(scene: &mut Value, axis: &str, v: &str) -> Result<(), Error> {
    let x = v
        .trim()
        .parse::<f64>()
        .ok()
        .filter(|x| x.is_finite())
        .ok_or_else(|| Error::invalid(axis, format!("'{v}' is not a finite number")))?;
    let camera = scene
        .get_mut("camera")
        .and_then(Value::as_object_mut)
        .ok_or_else(|| Error::invalid("camera", "missing (required to sweep the view)"))?;
    let pos = camera_vector(camera, "position_m")?;
    let look = camera_vector(camera, "look_at_m")?;
    let rel = [pos[0] - look[0], pos[1] - look[1], pos[2] - look[2]];
    let put = |camera: &mut Map<String, Value>, name: &str, p: [f64; 3]| {
        camera.insert(
            name.to_string(),
            Value::Array(p.iter().map(|&c| json_number(c)).collect()),
        );
    };
    if axis == "view_distance_m" {
        if !(x > 0.0 && x <= 1.0e7) {
            return Err(Error::out_of_range(axis, x, "greater than 0, up to 1e7 m"));
        }
        let d = (rel[0] * rel[0] + rel[1] * rel[1] + rel[2] * rel[2]).sqrt();
        if d == 0.0 {
            return Err(Error::invalid(
                "camera.look_at_m",
                "equals camera.position_m: the camera looks nowhere",
            ));
        }
        let p = [0, 1, 2].map(|a| look[a] + rel[a] * (x / d));
        put(camera, "position_m", p);
        return Ok(());
    }
    if !(-3600.0..=3600.0).contains(&x) {
        return Err(Error::out_of_range(axis, x, "-3600 to 3600 degrees"));
    }
    // Azimuth from +y towards +x: a turn by θ maps (x, y) to (x cos θ + y sin θ, y cos θ − x sin θ).
    let (s, c) = x.to_radians().sin_cos();
    let turn = |q: [f64; 3]| [q[0] * c + q[1] * s, q[1] * c - q[0] * s, q[2]];
    let r = turn(rel);
    put(camera, "position_m", [0, 1, 2].map(|a| look[a] + r[a]));
    if camera.contains_key("up") {
        let up = camera_vector(camera, "up")?;
        put(camera, "up", turn(up));
    }
    Ok(())
}
