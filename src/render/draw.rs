//! Draws one [`Frame`] into a bitmap: a 3/4 perspective view on the left, side (Y up, looking
//! across the longer horizontal travel) and top (X-Z) orthographic views on the right, a legend and a time stamp. Surfaces use the painter's algorithm.

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use glam::Vec3;

use super::camera::{Bounds, Camera, Panel};
use super::frame::{Frame, RenderError};

const BACKGROUND: RGBColor = RGBColor(250, 250, 248);
const PANEL_BORDER: RGBColor = RGBColor(200, 200, 200);
const TEXT: RGBColor = RGBColor(30, 30, 30);
const PACKAGE: RGBColor = RGBColor(90, 150, 220);
const PACKAGE_EDGE: RGBColor = RGBColor(40, 80, 140);
const DISC: RGBColor = RGBColor(235, 140, 40);
const CUP: RGBColor = RGBColor(60, 60, 60);
const RECORDED: RGBColor = RGBColor(215, 30, 40);
const SIMULATED_MARKER: RGBColor = RGBColor(20, 140, 60);
/// Sheets are see-through so the disc inside the envelope stays visible.
const PACKAGE_ALPHA: f64 = 0.45;
/// Light comes from above, slightly from the front-left; shading is two-sided.
const LIGHT: Vec3 = Vec3::new(-0.3, 0.9, 0.3);
const MARGIN_PX: f32 = 14.0;
/// Sides of the polygon that stands in for the disc's circular faces.
const DISC_SEGMENTS: usize = 36;
/// Title of the perspective panel, whose camera follows the package centroid.
const FOLLOW_TITLE: &str = "3/4 view, following the package";

/// Picture size and the three cameras, fixed for a whole animation so the scene does not jump.
#[derive(Clone, Debug)]
pub struct View {
    width: u32,
    height: u32,
    cameras: [(Camera, Panel, &'static str); 3],
    sizes: Sizes,
}

impl View {
    /// Lays out a `width` x `height` picture. The side and top views always show all of `scene`; the
    /// 3/4 view is zoomed to fit `close_up` (a box the size of the package) and follows the package.
    pub fn new(scene: &Bounds, close_up: &Bounds, width: u32, height: u32) -> Self {
        let (w, h) = (width as i32, height as i32);
        let left = Panel {
            x: 0,
            y: 0,
            width: w * 9 / 16,
            height: h,
        };
        let side = Panel {
            x: left.width,
            y: 0,
            width: w - left.width,
            height: h / 2,
        };
        let top = Panel {
            y: h / 2,
            height: h - h / 2,
            ..side
        };
        // Leave room at the top of each panel for its title (and the heading on the left).
        // Cameras work in each panel's own pixel coordinates.
        let title_room = |panel: Panel, room: i32| Panel {
            x: 0,
            y: room,
            width: panel.width,
            height: panel.height - room,
        };
        // Look across the longer horizontal travel, so the side view shows the motion.
        let (side_forward, side_title) = if scene.max.z - scene.min.z > scene.max.x - scene.min.x {
            (Vec3::NEG_X, "side (-Z right, Y up)")
        } else {
            (Vec3::NEG_Z, "side (X right, Y up)")
        };
        let sizes = Sizes::for_height(height);
        Self {
            width,
            height,
            sizes,
            cameras: [
                (
                    Camera::perspective(
                        close_up,
                        -35.0,
                        28.0,
                        2.2,
                        title_room(left, sizes.text(50)),
                        MARGIN_PX,
                    ),
                    left,
                    FOLLOW_TITLE,
                ),
                (
                    Camera::orthographic(
                        scene,
                        side_forward,
                        Vec3::Y,
                        title_room(side, sizes.text(22)),
                        MARGIN_PX,
                    ),
                    side,
                    side_title,
                ),
                (
                    Camera::orthographic(
                        scene,
                        Vec3::NEG_Y,
                        Vec3::NEG_Z,
                        title_room(top, sizes.text(22)),
                        MARGIN_PX,
                    ),
                    top,
                    "top (X right, Z down)",
                ),
            ],
        }
    }

    /// Picture width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The perspective camera (left panel); tests use it to find where a point lands.
    #[cfg(test)]
    pub fn main_camera(&self) -> &Camera {
        &self.cameras[0].0
    }
}

/// Pixel sizes of marks and text, scaled with the picture height (720 px = 1) so small GIF frames
/// stay readable: text shrinks less than marks.
#[derive(Clone, Copy, Debug)]
struct Sizes {
    mark: f32,
    text: f32,
}

impl Sizes {
    fn for_height(height: u32) -> Self {
        let scale = height as f32 / 720.0;
        Self {
            mark: scale.max(0.65),
            text: scale.max(0.75),
        }
    }

    /// A marker size or line width.
    fn mark(self, pixels: i32) -> i32 {
        ((pixels as f32 * self.mark).round() as i32).max(1)
    }

    /// A font size or a distance tied to text.
    fn text(self, pixels: i32) -> i32 {
        ((pixels as f32 * self.text).round() as i32).max(1)
    }
}

/// How a legend entry is marked.
enum Swatch {
    Dot,
    Ring,
    Cross,
}

/// One filled triangle in screen space, kept with its depth for back-to-front sorting.
struct ScreenTriangle {
    corners: [(i32, i32); 3],
    depth: f32,
    fill: RGBAColor,
    edge: Option<RGBAColor>,
}

fn to_draw_error(err: impl std::fmt::Display) -> RenderError {
    RenderError::Draw(err.to_string())
}

/// Renders `frame` as seen through `view` into a packed RGB buffer. Each panel is drawn into its
/// own bitmap first, so nothing spills into its neighbours, then the caption goes on top.
pub fn render(frame: &Frame, view: &View) -> Result<Vec<u8>, RenderError> {
    let (width, height) = (view.width as usize, view.height as usize);
    let mut picture = vec![0u8; width * height * 3];
    let disc_triangles = frame
        .disc
        .as_ref()
        .map(|disc| disc.triangles(DISC_SEGMENTS));
    for (fixed_camera, panel, title) in &view.cameras {
        let camera = &match (*title == FOLLOW_TITLE, centroid(frame.package)) {
            (true, Some(centre)) => fixed_camera.aimed_at(centre),
            _ => fixed_camera.clone(),
        };
        let (panel_width, panel_height) = (panel.width as usize, panel.height as usize);
        let mut pixels = vec![0u8; panel_width * panel_height * 3];
        {
            let area =
                BitMapBackend::with_buffer(&mut pixels, (panel.width as u32, panel.height as u32))
                    .into_drawing_area();
            draw_panel(
                &area,
                camera,
                frame,
                disc_triangles.as_deref(),
                title,
                view.sizes,
            )?;
            area.present().map_err(to_draw_error)?;
        }
        for (row, line) in pixels.chunks_exact(panel_width * 3).enumerate() {
            let start = ((panel.y as usize + row) * width + panel.x as usize) * 3;
            picture[start..start + line.len()].copy_from_slice(line);
        }
    }
    {
        let area =
            BitMapBackend::with_buffer(&mut picture, (view.width, view.height)).into_drawing_area();
        draw_caption(&area, frame, view.sizes)?;
        area.present().map_err(to_draw_error)?;
    }
    Ok(picture)
}

/// One view of the scene, in the panel's own pixel coordinates.
fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    camera: &Camera,
    frame: &Frame,
    disc_triangles: Option<&[[[f32; 3]; 3]]>,
    title: &str,
    sizes: Sizes,
) -> Result<(), RenderError> {
    area.fill(&BACKGROUND).map_err(to_draw_error)?;
    let mut triangles = Vec::with_capacity(frame.triangles.len() + 4 * DISC_SEGMENTS);
    for tri in frame.triangles {
        let corners = tri.map(|k| frame.package.get(k as usize).copied());
        if let [Some(a), Some(b), Some(c)] = corners {
            let fill = shade(PACKAGE, [a, b, c]).mix(PACKAGE_ALPHA);
            triangles.extend(screen_triangle(
                camera,
                [a, b, c],
                fill,
                Some(PACKAGE_EDGE.mix(0.35)),
            ));
        }
    }
    for tri in disc_triangles.into_iter().flatten() {
        triangles.extend(screen_triangle(
            camera,
            *tri,
            shade(DISC, *tri).to_rgba(),
            None,
        ));
    }
    // Painter's algorithm: farthest first.
    triangles.sort_by(|a, b| b.depth.total_cmp(&a.depth));
    for tri in &triangles {
        let outline = [
            tri.corners[0],
            tri.corners[1],
            tri.corners[2],
            tri.corners[0],
        ];
        area.draw(&Polygon::new(tri.corners.to_vec(), tri.fill.filled()))
            .map_err(to_draw_error)?;
        if let Some(edge) = tri.edge {
            area.draw(&PathElement::new(outline.to_vec(), edge))
                .map_err(to_draw_error)?;
        }
    }
    for &cup in frame.cups {
        draw_dot(area, camera, cup, sizes.mark(2), CUP.filled())?;
    }
    for &site in frame.simulated_markers {
        draw_dot(area, camera, site, sizes.mark(3), SIMULATED_MARKER.filled())?;
    }
    for &marker in frame.recorded_markers {
        draw_dot(
            area,
            camera,
            marker,
            sizes.mark(4),
            RECORDED.stroke_width(sizes.mark(2) as u32),
        )?;
    }
    if let Some(object) = frame.recorded_object {
        draw_cross(
            area,
            camera,
            object,
            sizes.mark(7),
            RECORDED.stroke_width(sizes.mark(3) as u32),
        )?;
    }
    draw_panel_frame(area, camera, title, sizes)
}

/// Mean of the finite points, if any.
fn centroid(points: &[[f32; 3]]) -> Option<Vec3> {
    let finite = points
        .iter()
        .map(|&p| Vec3::from(p))
        .filter(|p| p.is_finite());
    let (sum, count) = finite.fold((glam::DVec3::ZERO, 0usize), |(sum, count), p| {
        (sum + p.as_dvec3(), count + 1)
    });
    (count > 0).then(|| (sum / count as f64).as_vec3())
}

/// Lambert shading with a two-sided normal, so both faces of a sheet look lit.
fn shade(base: RGBColor, [a, b, c]: [[f32; 3]; 3]) -> RGBColor {
    let (a, b, c) = (Vec3::from(a), Vec3::from(b), Vec3::from(c));
    let normal = (b - a).cross(c - a).normalize_or_zero();
    let light = normal.dot(LIGHT.normalize()).abs();
    let factor = 0.45 + 0.55 * light;
    let scale = |v: u8| (v as f32 * factor).round().clamp(0.0, 255.0) as u8;
    RGBColor(scale(base.0), scale(base.1), scale(base.2))
}

fn screen_triangle(
    camera: &Camera,
    corners: [[f32; 3]; 3],
    fill: RGBAColor,
    edge: Option<RGBAColor>,
) -> Option<ScreenTriangle> {
    if corners.iter().flatten().any(|v| !v.is_finite()) {
        return None;
    }
    let projected = corners.map(|p| camera.project(p));
    Some(ScreenTriangle {
        corners: projected.map(|(x, y, _)| (x.round() as i32, y.round() as i32)),
        depth: projected.iter().map(|p| p.2).sum::<f32>() / 3.0,
        fill,
        edge,
    })
}

fn pixel(camera: &Camera, point: [f32; 3]) -> Option<(i32, i32)> {
    if !point.iter().all(|v| v.is_finite()) {
        return None;
    }
    let (x, y, _) = camera.project(point);
    Some((x.round() as i32, y.round() as i32))
}

fn draw_dot<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    camera: &Camera,
    point: [f32; 3],
    radius: i32,
    style: ShapeStyle,
) -> Result<(), RenderError> {
    if let Some(centre) = pixel(camera, point) {
        area.draw(&Circle::new(centre, radius, style))
            .map_err(to_draw_error)?;
    }
    Ok(())
}

fn draw_cross<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    camera: &Camera,
    point: [f32; 3],
    half: i32,
    style: ShapeStyle,
) -> Result<(), RenderError> {
    if let Some((x, y)) = pixel(camera, point) {
        for (dx, dy) in [(half, half), (half, -half)] {
            area.draw(&PathElement::new(
                vec![(x - dx, y - dy), (x + dx, y + dy)],
                style,
            ))
            .map_err(to_draw_error)?;
        }
    }
    Ok(())
}

/// Border, title and (for the orthographic views) a 10 cm scale bar.
fn draw_panel_frame<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    camera: &Camera,
    title: &str,
    sizes: Sizes,
) -> Result<(), RenderError> {
    let (width, height) = area.dim_in_pixel();
    let (x0, y0) = (0, 0);
    let (x1, y1) = (width as i32 - 1, height as i32 - 1);
    area.draw(&PathElement::new(
        vec![(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)],
        PANEL_BORDER,
    ))
    .map_err(to_draw_error)?;
    let title_y = if title == FOLLOW_TITLE {
        y0 + sizes.text(34)
    } else {
        y0 + sizes.text(5)
    };
    area.draw(&Text::new(
        title.to_string(),
        (x0 + sizes.text(10), title_y),
        ("sans-serif", sizes.text(15)).into_font().color(&TEXT),
    ))
    .map_err(to_draw_error)?;
    if title == FOLLOW_TITLE {
        return Ok(());
    }
    let bar = (0.1 * camera.pixels_per_metre()).round() as i32;
    let margin = sizes.text(12);
    let (bx, by) = (x1 - margin - bar, y1 - margin);
    area.draw(&PathElement::new(
        vec![(bx, by - 4), (bx, by), (bx + bar, by), (bx + bar, by - 4)],
        TEXT.stroke_width(2),
    ))
    .map_err(to_draw_error)?;
    let label_style = ("sans-serif", sizes.text(13))
        .into_font()
        .color(&TEXT)
        .pos(Pos::new(HPos::Center, VPos::Bottom));
    area.draw(&Text::new("10 cm", (bx + bar / 2, by - 5), label_style))
        .map_err(to_draw_error)?;
    Ok(())
}

/// Title and time stamp in the top-left corner, legend in the bottom-left corner.
fn draw_caption<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    frame: &Frame,
    sizes: Sizes,
) -> Result<(), RenderError> {
    let (_, height) = area.dim_in_pixel();
    let height = height as i32;
    let heading = format!("{}   t = {:+.3} s", frame.title, frame.time);
    area.draw(&Text::new(
        heading,
        (sizes.text(10), sizes.text(8)),
        ("sans-serif", sizes.text(22)).into_font().color(&TEXT),
    ))
    .map_err(to_draw_error)?;
    let mut entries: Vec<(&str, RGBColor, Swatch)> = vec![("package (sim)", PACKAGE, Swatch::Dot)];
    if frame.disc.is_some() {
        entries.push(("disc (sim)", DISC, Swatch::Dot));
    }
    if !frame.cups.is_empty() {
        entries.push(("suction cups (sim)", CUP, Swatch::Dot));
    }
    if !frame.simulated_markers.is_empty() {
        entries.push(("marker sites (sim)", SIMULATED_MARKER, Swatch::Dot));
    }
    if !frame.recorded_markers.is_empty() {
        entries.push(("markers (recorded)", RECORDED, Swatch::Ring));
    }
    if frame.recorded_object.is_some() {
        entries.push(("object centre (recorded)", RECORDED, Swatch::Cross));
    }
    let line = sizes.text(18);
    let unit = |v: i32| sizes.text(v);
    let mut y = height - unit(12) - line * entries.len() as i32;
    for (label, colour, swatch) in entries {
        let centre = (unit(18), y + unit(8));
        let (left, right, top, bottom) = (unit(12), unit(24), y + unit(2), y + unit(14));
        match swatch {
            Swatch::Dot => area.draw(&Circle::new(centre, unit(5), colour.filled())),
            Swatch::Ring => area.draw(&Circle::new(
                centre,
                unit(5),
                colour.stroke_width(unit(2) as u32),
            )),
            Swatch::Cross => area.draw(&PathElement::new(
                vec![
                    (left, top),
                    (right, bottom),
                    centre,
                    (left, bottom),
                    (right, top),
                ],
                colour.stroke_width(unit(3) as u32),
            )),
        }
        .map_err(to_draw_error)?;
        area.draw(&Text::new(
            label,
            (unit(30), y),
            ("sans-serif", unit(14)).into_font().color(&TEXT),
        ))
        .map_err(to_draw_error)?;
        y += line;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(x: f32, z: f32) -> Bounds {
        let mut bounds = Bounds::empty();
        bounds.include([0.0, 0.0, 0.0]);
        bounds.include([x, 0.3, z]);
        bounds
    }

    #[test]
    fn side_view_looks_across_the_longer_horizontal_travel() {
        let title = |bounds: Bounds| View::new(&bounds, &bounds, 640, 360).cameras[1].2;
        assert_eq!(title(scene(1.0, 0.3)), "side (X right, Y up)");
        assert_eq!(title(scene(0.3, 1.0)), "side (-Z right, Y up)");
    }
}
