//! Cooperative cancellation inside the table builds and the output rows: the density
//! table and a product's output rows ask the cancel check once per row, the precise
//! multiple-scattering table once per order, so a cancelled request stops within a row or so of the check that said "stop" instead
//! of finishing the build. Work is measured by counting the checks (each one starts a row), never
//! by the wall clock.

use skybake_engine::engine::{Engine, Table};
use skybake_physics::Error;
use skybake_product::params::RequestParams;
use skybake_product::{ProductKind, ProductRequest};
use std::sync::atomic::{AtomicUsize, Ordering};

/// A precise draft sky on 4 wavelengths with 64 elevation rows (64 × 3 output entries).
fn sky_request() -> ProductRequest {
    let pairs: Vec<(String, String)> = [
        ("method", "precise"),
        ("quality", "draft"),
        ("wavelengths", "440,550,610,680"),
        ("sun_elevation_deg", "25"),
        ("elevation_count", "64"),
        ("azimuth_count", "3"),
    ]
    .iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    let params = RequestParams::from_pairs(pairs).unwrap();
    ProductRequest::from_params(ProductKind::Sky, &params).unwrap()
}

/// A check that counts its calls and says "cancelled" from call `stop_at` on (never when 0).
struct Counter {
    calls: AtomicUsize,
    stop_at: usize,
}

impl Counter {
    fn new(stop_at: usize) -> Self {
        Counter {
            calls: AtomicUsize::new(0),
            stop_at,
        }
    }
    fn check(&self) -> bool {
        let n = self.calls.fetch_add(1, Ordering::SeqCst) + 1;
        self.stop_at != 0 && n >= self.stop_at
    }
    fn calls(&self) -> usize {
        self.calls.load(Ordering::SeqCst)
    }
}

/// Rows that may start after the stopping check: the other threads may each be between their
/// own check and the stop flag.
fn slack() -> usize {
    rayon::current_num_threads() + 1
}

#[test]
fn a_cancelled_cold_sky_stops_inside_the_density_table() {
    let request = sky_request();
    // The whole cold computation: every row of every build asks once.
    let full = Counter::new(0);
    request
        .compute_cancellable(&Engine::new(), &|| full.check())
        .unwrap();
    // The density table alone: one check per row of radius.
    let density_rows = skybake_physics::atmosphere::shared::TRANSMITTANCE_N_R;
    assert!(
        full.calls() > density_rows + 64,
        "{} checks in a cold sky: the precise table's orders and the output's rows ask too",
        full.calls()
    );

    let engine = Engine::new();
    let stopped = Counter::new(3);
    let err = request
        .compute_cancellable(&engine, &|| stopped.check())
        .unwrap_err();
    assert_eq!(err, Error::Cancelled);
    assert!(
        stopped.calls() <= 3 + slack(),
        "{} rows started after cancellation at row 3 of {density_rows}",
        stopped.calls()
    );
    // The half-built table was not kept: the next request builds it whole and succeeds.
    request.compute(&engine).unwrap();
    assert_eq!(engine.table_builds(Table::Density), 2);
}

#[test]
fn a_cancelled_cold_sky_stops_inside_the_precise_table() {
    let request = sky_request();
    let density_rows = skybake_physics::atmosphere::shared::TRANSMITTANCE_N_R;
    // The density table asks `density_rows` times, the evaluator once; then the precise table
    // between its orders.
    let stop_at = density_rows + 1 + 2;
    let engine = Engine::new();
    let stopped = Counter::new(stop_at);
    let err = request
        .compute_cancellable(&engine, &|| stopped.check())
        .unwrap_err();
    assert_eq!(err, Error::Cancelled);
    assert!(
        stopped.calls() <= stop_at + slack(),
        "{} checks after cancellation at check {stop_at}",
        stopped.calls()
    );
    // The precise table was not kept (the next run builds it again: more checks than a warm
    // run); the density table was.
    let rebuild = Counter::new(0);
    request
        .compute_cancellable(&engine, &|| rebuild.check())
        .unwrap();
    let warm = Counter::new(0);
    request
        .compute_cancellable(&engine, &|| warm.check())
        .unwrap();
    assert_eq!(engine.table_builds(Table::Density), 1);
    assert_eq!(engine.table_builds(Table::Precise), 1);
    assert!(
        rebuild.calls() > warm.calls() + 2,
        "the precise table was not built again ({} checks, warm {})",
        rebuild.calls(),
        warm.calls()
    );
}

#[test]
fn a_cancelled_warm_sky_stops_inside_its_output_rows() {
    let request = sky_request();
    let engine = Engine::new();
    request.compute(&engine).unwrap();
    // Warm: the evaluator's two stage checks, then one per output row (64 of them).
    let full = Counter::new(0);
    request
        .compute_cancellable(&engine, &|| full.check())
        .unwrap();
    assert!(full.calls() >= 64, "{} checks", full.calls());
    let stopped = Counter::new(5);
    let err = request
        .compute_cancellable(&engine, &|| stopped.check())
        .unwrap_err();
    assert_eq!(err, Error::Cancelled);
    assert!(
        stopped.calls() <= 5 + slack(),
        "{} of {} rows started after cancellation at check 5",
        stopped.calls(),
        full.calls()
    );
}

#[test]
fn a_cancelled_bundle_stops_inside_its_textures() {
    // The real-time bundle (Bruneton's layout) on tables already built: its transmittance
    // texture asks once per row (64; a row after the stop asks and returns), then once before
    // the scattering texture, whose 32 × 128 rows would each ask again.
    let params =
        RequestParams::from_pairs(vec![("quality".to_string(), "draft".to_string())]).unwrap();
    let request = skybake_product::lut::LutRequest::from_params(&params).unwrap();
    let engine = Engine::new();
    engine.shared(&request.spec).unwrap().precise();
    let stop_at = 10;
    let stopped = Counter::new(stop_at);
    let err = request
        .compute_unless(&engine, &|| stopped.check())
        .unwrap_err();
    assert_eq!(err, Error::Cancelled);
    let transmittance_rows = skybake_lut::param::TRANSMITTANCE_HEIGHT;
    assert!(
        stopped.calls() <= transmittance_rows + 1,
        "{} checks: the build went past the transmittance texture ({transmittance_rows} rows)",
        stopped.calls()
    );
}
