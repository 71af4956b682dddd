//! The atmosphere products, the spectra and the solar position, against their external references (DISORT, the spherical Monte Carlo, Bruneton, pvlib, colour-science), and the atmosphere planner.

mod atmosphere_aerosol;
mod atmosphere_cancel;
mod atmosphere_fog;
mod atmosphere_haze;
mod atmosphere_night;
mod atmosphere_products;
mod atmosphere_robustness;
mod atmosphere_twilight;
mod atmosphere_validation;
mod external;
mod lut;
mod lut_skyview;
mod plan;
mod report_accuracy;
mod solar_position;
mod spectrum_colour;
mod spectrum_photometry;
