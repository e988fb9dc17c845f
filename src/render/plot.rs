//! Plots of a replay against its recording (the paper's Fig. 10 and the error over time), written
//! as PNG files with plotters.

use std::path::Path;

use anyhow::Context;
use plotters::prelude::*;
use rlpkg_env::transport::TracePoint;
use rlpkg_replay::loss::TrajectoryLoss;
use rlpkg_replay::Target;

/// Picture size of the plots.
const PLOT_SIZE: (u32, u32) = (900, 600);

/// Draws a [`PLOT_SIZE`] picture into a temporary PNG beside `path`, then renames it into place.
fn write_plot(
    path: &Path,
    draw: impl FnOnce(&DrawingArea<BitMapBackend, plotters::coord::Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    write_plot_sized(path, PLOT_SIZE, draw)
}

/// As [`write_plot`] with the picture's size in pixels.
fn write_plot_sized(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend, plotters::coord::Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    super::frame::ensure_font()?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let temporary = path.with_file_name(format!(".{name}.{}.tmp.png", std::process::id()));
    let result: anyhow::Result<()> = (|| {
        let area = BitMapBackend::new(&temporary, size).into_drawing_area();
        area.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
        draw(&area)?;
        area.present().map_err(|e| anyhow::anyhow!("{e}"))?;
        drop(area);
        std::fs::rename(&temporary, path)?;
        Ok(())
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    result.with_context(|| format!("writing {}", path.display()))
}

/// Fig. 10: mean distance from each marker site to the nearest recorded marker, over the package
/// (sites at their row-0 positions, top view x-z), colour from green (0) to red (max).
pub fn write_marker_error_plot(path: &Path, target: &Target, errors: &[f64]) -> anyhow::Result<()> {
    let sites = &target.sites();
    let finite_max = errors
        .iter()
        .copied()
        .filter(|e| e.is_finite())
        .fold(0.0f64, f64::max)
        .max(1e-6);
    let (x0, x1) = extent(sites.iter().map(|p| p[0] as f64));
    let (z0, z1) = extent(sites.iter().map(|p| p[2] as f64));
    write_plot(path, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!(
                    "{}: mean error per marker site (max {:.1} mm)",
                    target.id,
                    finite_max * 1e3
                ),
                ("sans-serif", 22),
            )
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(x0 - 0.03..x1 + 0.03, z0 - 0.03..z1 + 0.03)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc("x (m)")
            .y_desc("z (m)")
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .draw_series(sites.iter().zip(errors).map(|(p, &e)| {
                let f = if e.is_finite() { e / finite_max } else { 1.0 };
                let colour = RGBColor((255.0 * f) as u8, (200.0 * (1.0 - f)) as u8, 40);
                Circle::new((p[0] as f64, p[2] as f64), 12, colour.filled())
            }))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .draw_series(sites.iter().zip(errors).map(|(p, &e)| {
                Text::new(
                    format!("{:.0}", e * 1e3),
                    (p[0] as f64 + 0.006, p[2] as f64 + 0.006),
                    ("sans-serif", 13),
                )
            }))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        Ok(())
    })
}

/// The per-frame package Chamfer distance and object error (as a distance, m) over time.
pub fn write_loss_plot(path: &Path, target: &Target, loss: &TrajectoryLoss) -> anyhow::Result<()> {
    let cd: Vec<(f64, f64)> = loss
        .frames
        .iter()
        .map(|f| (target.times[f.frame], f.chamfer_m))
        .collect();
    let obj: Vec<(f64, f64)> = loss
        .frames
        .iter()
        .map(|f| (target.times[f.frame], f.object_sq_m2.sqrt()))
        .collect();
    let y_max = cd
        .iter()
        .chain(&obj)
        .map(|p| p.1)
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max)
        .max(1e-3)
        * 1.1;
    let t_max = target.duration().max(1e-3);
    write_plot(path, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!("{}: error over time", target.id),
                ("sans-serif", 22),
            )
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..t_max, 0.0..y_max)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc("trajectory time (s)")
            .y_desc("error (m)")
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .draw_series(LineSeries::new(cd, &BLUE))
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .label("package Chamfer distance")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
        chart
            .draw_series(LineSeries::new(obj, &RED))
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .label("object position error")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        Ok(())
    })
}

/// Side of one panel of a corner plot (pixels).
const CORNER_PANEL: u32 = 150;

/// A corner plot of posterior draws: for every pair of parameters a scatter of the draws over the
/// whole search box (unit-cube coordinates: decades for log parameters), and on the diagonal each
/// parameter's histogram; the best draw in red. `unit_draws` and `best` are in the unit cube.
pub fn write_corner_plot(
    path: &Path,
    names: &[&str],
    unit_draws: &[Vec<f64>],
    best: &[f64],
) -> anyhow::Result<()> {
    let d = names.len();
    let side = CORNER_PANEL * d as u32 + 60;
    write_plot_sized(path, (side, side), |area| {
        let inner = area.margin(10, 50, 50, 10);
        let panels = inner.split_evenly((d, d));
        for (index, panel) in panels.iter().enumerate() {
            let (row, col) = (index / d, index % d);
            if col > row {
                continue;
            }
            let mut builder = ChartBuilder::on(panel);
            builder.margin(3);
            if row == d - 1 {
                builder.x_label_area_size(14);
            }
            if col == 0 {
                builder.y_label_area_size(14);
            }
            let e = |e: plotters::drawing::DrawingAreaErrorKind<_>| anyhow::anyhow!("{e}");
            if row == col {
                let bins = 20usize;
                let mut counts = vec![0usize; bins];
                for draw in unit_draws {
                    let b = ((draw[col] * bins as f64) as usize).min(bins - 1);
                    counts[b] += 1;
                }
                let top = counts.iter().copied().max().unwrap_or(1).max(1) as f64 * 1.1;
                let mut chart = builder.build_cartesian_2d(0.0..1.0, 0.0..top).map_err(e)?;
                let mut mesh = chart.configure_mesh();
                mesh.disable_mesh().y_labels(0).x_labels(0);
                if row == d - 1 {
                    mesh.x_desc(names[col]);
                }
                mesh.draw().map_err(e)?;
                chart
                    .draw_series(counts.iter().enumerate().map(|(b, &n)| {
                        let x0 = b as f64 / bins as f64;
                        Rectangle::new(
                            [(x0, 0.0), (x0 + 1.0 / bins as f64, n as f64)],
                            BLUE.mix(0.5).filled(),
                        )
                    }))
                    .map_err(e)?;
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![(best[col], 0.0), (best[col], top)],
                        RED,
                    )))
                    .map_err(e)?;
            } else {
                let mut chart = builder.build_cartesian_2d(0.0..1.0, 0.0..1.0).map_err(e)?;
                let mut mesh = chart.configure_mesh();
                mesh.disable_mesh().x_labels(0).y_labels(0);
                if row == d - 1 {
                    mesh.x_desc(names[col]);
                }
                if col == 0 {
                    mesh.y_desc(names[row]);
                }
                mesh.draw().map_err(e)?;
                chart
                    .draw_series(
                        unit_draws
                            .iter()
                            .map(|p| Circle::new((p[col], p[row]), 1, BLUE.mix(0.4).filled())),
                    )
                    .map_err(e)?;
                chart
                    .draw_series(std::iter::once(Circle::new(
                        (best[col], best[row]),
                        3,
                        RED.filled(),
                    )))
                    .map_err(e)?;
            }
        }
        Ok(())
    })
}

/// Cost per iteration of an optimisation: one line per named series of `(iteration, cost)`.
pub fn write_cost_plot(
    path: &Path,
    title: &str,
    series: &[(&str, Vec<(f64, f64)>)],
) -> anyhow::Result<()> {
    let points = || series.iter().flat_map(|(_, s)| s.iter());
    let (x0, x1) = extent(points().map(|p| p.0));
    let (y0, y1) = extent(points().map(|p| p.1).filter(|v| v.is_finite()));
    let (x1, pad) = (x1.max(x0 + 1.0), ((y1 - y0) * 0.05).max(1e-3));
    write_plot(path, |area| {
        let mut chart = ChartBuilder::on(area)
            .caption(title, ("sans-serif", 22))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x0..x1, y0 - pad..y1 + pad)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc("iteration")
            .y_desc("cost")
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        for (k, (name, line)) in series.iter().enumerate() {
            let colour = DRIVER_COLOURS[k % DRIVER_COLOURS.len()];
            chart
                .draw_series(LineSeries::new(line.clone(), &colour))
                .map_err(|e| anyhow::anyhow!("{e}"))?
                .label(*name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        Ok(())
    })
}

fn extent(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    })
}

/// Colours of the drivers in a transport plot, in order.
const DRIVER_COLOURS: [RGBColor; 6] = [
    RGBColor(200, 30, 30),
    RGBColor(30, 80, 200),
    RGBColor(30, 150, 60),
    RGBColor(150, 60, 170),
    RGBColor(230, 130, 20),
    RGBColor(90, 90, 90),
];

/// One transport episode per driver: commanded path speed, tool tilt, the object's displacement
/// relative to the tool since pick, and the peak seal utilisation, over time (four panels).
pub fn write_transport_plot(
    path: &Path,
    title: &str,
    drivers: &[(String, Vec<TracePoint>)],
) -> anyhow::Result<()> {
    type Quantity = (&'static str, fn(&TracePoint, &TracePoint) -> f64);
    let quantities: [Quantity; 4] = [
        ("path speed (m/s)", |p, _| p.path_speed_m_s),
        ("tool tilt (deg)", |p, _| p.tool_tilt_deg),
        ("object displacement in tool (cm)", |p, start| {
            let d: f64 = (0..3)
                .map(|k| (p.object_in_tool_m[k] - start.object_in_tool_m[k]).powi(2))
                .sum();
            100.0 * d.sqrt()
        }),
        ("peak seal utilisation", |p, _| p.peak_seal_utilisation),
    ];
    let t_max = drivers
        .iter()
        .flat_map(|(_, trace)| trace.iter().map(|p| p.time_s))
        .fold(1e-3, f64::max);
    write_plot_sized(path, (1200, 800), |area| {
        let area = area
            .titled(title, ("sans-serif", 22))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        for (panel, (label, value)) in area.split_evenly((2, 2)).iter().zip(quantities) {
            let series: Vec<Vec<(f64, f64)>> = drivers
                .iter()
                .map(|(_, trace)| {
                    let start = trace.first().copied();
                    trace
                        .iter()
                        .zip(std::iter::repeat(start))
                        .filter_map(|(p, s)| s.map(|s| (p.time_s, value(p, &s))))
                        .filter(|(_, v)| v.is_finite())
                        .collect()
                })
                .collect();
            let y_max = series.iter().flatten().map(|p| p.1).fold(1e-3, f64::max) * 1.1;
            let mut chart = ChartBuilder::on(panel)
                .margin(12)
                .x_label_area_size(35)
                .y_label_area_size(50)
                .build_cartesian_2d(0.0..t_max, 0.0..y_max)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            chart
                .configure_mesh()
                .x_desc("time since pick (s)")
                .y_desc(label)
                .draw()
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            for (k, ((driver, _), points)) in drivers.iter().zip(series).enumerate() {
                let colour = DRIVER_COLOURS[k % DRIVER_COLOURS.len()];
                chart
                    .draw_series(LineSeries::new(points, colour.stroke_width(2)))
                    .map_err(|e| anyhow::anyhow!("{e}"))?
                    .label(driver.as_str())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use rlpkg_sim::{Placement, ToolTrajectory};

    use super::*;

    /// A replay target of two compared frames over three marker sites.
    fn target() -> Target {
        let sites = vec![[0.0, 0.25, 0.0], [0.1, 0.25, 0.0], [0.0, 0.25, 0.1]];
        Target {
            id: "PLOT".into(),
            placement: Placement::new([0.0, 0.25, 0.0], [0.05, 0.26, 0.05], [0.05, 0.2, 0.05]),
            object_mass_kg: 0.4,
            tool: Arc::new(ToolTrajectory::hold(
                [0.05, 0.4, 0.05],
                [0.0, 0.0, 0.0, 1.0],
            )),
            initial_markers: sites,
            lower_markers: Vec::new(),
            times: vec![0.0, 0.5],
            markers: vec![vec![[0.0, 0.25, 0.0]]; 2],
            marker_tracks: vec![vec![0]; 2],
            marker_sites: vec![vec![Some(0)]; 2],
            phases: vec![rlpkg_replay::Phase::Hold; 2],
            tracking: Default::default(),
            object: vec![[0.05, 0.2, 0.05]; 2],
        }
    }

    #[test]
    fn a_corner_plot_is_a_whole_png_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("corner.png");
        let draws: Vec<Vec<f64>> = (0..50)
            .map(|i| vec![i as f64 / 50.0, 0.5, (i % 7) as f64 / 7.0])
            .collect();
        write_corner_plot(&path, &["a", "b", "c"], &draws, &[0.2, 0.5, 0.9]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
    }

    #[test]
    fn plots_are_written_as_whole_png_files() {
        let dir = tempfile::tempdir().unwrap();
        let target = target();
        let mut loss = TrajectoryLoss::new("PLOT");
        for k in 0..2 {
            let simulated = [[0.0, 0.25 + 0.01 * k as f64, 0.0]];
            loss.push_frame(&rlpkg_replay::loss::FrameComparison {
                frame: k,
                simulated_points: &simulated,
                markers: &target.markers[k],
                marker_sites: &target.marker_sites[k],
                simulated_object: &[0.05; 3],
                recorded_object: &[0.05; 3],
                phase: target.phases[k],
            });
        }
        let errors_png = dir.path().join("PLOT_marker_error.png");
        let loss_png = dir.path().join("PLOT_loss.png");
        write_marker_error_plot(&errors_png, &target, &[0.001, 0.004, f64::NAN]).unwrap();
        write_loss_plot(&loss_png, &target, &loss).unwrap();
        for path in [&errors_png, &loss_png] {
            let bytes = std::fs::read(path).unwrap();
            assert_eq!(&bytes[1..4], b"PNG", "{}", path.display());
            // IHDR: width and height, big-endian, at bytes 16..24.
            let width = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
            let height = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
            assert_eq!((width, height), PLOT_SIZE);
        }
        // No temporary file is left beside them; a missing folder is an error naming the file.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
        let missing = dir.path().join("absent").join("x_loss.png");
        let err = write_loss_plot(&missing, &target, &loss).unwrap_err();
        assert!(format!("{err:#}").contains("x_loss.png"), "{err:#}");
    }
}
