//! The calibration pattern: planar grid boards of dark squares, at known places in the
//! pattern frame. Each square's four corners are reference points; a few squares left out
//! (`missing`) break the grid's symmetry so that its orientation can be told in an image.

use nalgebra::{Point3, Vector3};
use thiserror::Error;

/// One planar board: `rows` × `cols` dark squares of side `square`, `pitch` apart (centre
/// to centre), the first square's outer corner at `origin`, columns along `u_axis` and rows
/// along `v_axis` (unit vectors in the board's plane). Square (r, c) covers
/// `origin + [c·pitch, c·pitch + square]·u + [r·pitch, r·pitch + square]·v`.
#[derive(Debug, Clone, PartialEq)]
pub struct GridBoard {
    pub origin: Point3<f64>,
    pub u_axis: Vector3<f64>,
    pub v_axis: Vector3<f64>,
    pub rows: u32,
    pub cols: u32,
    /// Side of a square, metres.
    pub square: f64,
    /// Centre-to-centre spacing, metres (more than `square`: white between squares).
    pub pitch: f64,
    /// Cells `(row, col)` left empty.
    pub missing: Vec<(u32, u32)>,
}

/// Which reference point: board, row, column, and corner (0..4, see [`GridBoard::corners`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct CornerId {
    pub board: usize,
    pub row: u32,
    pub col: u32,
    pub corner: usize,
}

/// One or more boards in one frame (the pattern frame).
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationPattern {
    pub boards: Vec<GridBoard>,
}

/// A pattern that cannot be used, naming the field (`boards[1].pitch`).
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("{field}: {message}")]
pub struct PatternError {
    pub field: String,
    pub message: String,
}

/// Axes this far from unit length or from perpendicular are refused.
const AXIS_TOLERANCE: f64 = 1e-6;
/// Most squares along a board's side. Printed targets have a few dozen at most; the bound
/// keeps every loop over a board's squares (checking, detection, the reference points) small
/// whatever a request says.
pub const MAX_BOARD_SIDE: u32 = 64;
/// Most boards in one pattern.
pub const MAX_BOARDS: usize = 8;
/// Most cells left out of one board: a few break its symmetry.
pub const MAX_MISSING: usize = 64;

impl GridBoard {
    /// Whether square (r, c) is printed.
    pub fn has(&self, row: u32, col: u32) -> bool {
        row < self.rows && col < self.cols && !self.missing.contains(&(row, col))
    }

    /// The four corners of square (r, c), in the order (0,0), (1,0), (1,1), (0,1) in the
    /// board's (u, v): along u first, then v.
    pub fn corners(&self, row: u32, col: u32) -> [Point3<f64>; 4] {
        let at = |du: f64, dv: f64| {
            self.origin
                + self.u_axis * (f64::from(col) * self.pitch + du)
                + self.v_axis * (f64::from(row) * self.pitch + dv)
        };
        let s = self.square;
        [at(0.0, 0.0), at(s, 0.0), at(s, s), at(0.0, s)]
    }

    /// The squares printed, row by row.
    pub fn squares(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        (0..self.rows)
            .flat_map(move |r| (0..self.cols).map(move |c| (r, c)))
            .filter(|&(r, c)| self.has(r, c))
    }

    /// The unit normal of the board (u × v).
    pub fn normal(&self) -> Vector3<f64> {
        self.u_axis.cross(&self.v_axis)
    }

    fn check(&self, i: usize) -> Result<(), PatternError> {
        let bad = |field: &str, message: String| PatternError {
            field: format!("boards[{i}].{field}"),
            message,
        };
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !finite(self.origin.coords.as_slice()) {
            return Err(bad("origin", "must be 3 finite numbers".into()));
        }
        for (name, axis) in [("u_axis", &self.u_axis), ("v_axis", &self.v_axis)] {
            if !finite(axis.as_slice()) || (axis.norm() - 1.0).abs() > AXIS_TOLERANCE {
                return Err(bad(
                    name,
                    format!("must be a unit vector, got {:?}", axis.as_slice()),
                ));
            }
        }
        if self.u_axis.dot(&self.v_axis).abs() > AXIS_TOLERANCE {
            return Err(bad("v_axis", "must be perpendicular to u_axis".into()));
        }
        for (name, n) in [("rows", self.rows), ("cols", self.cols)] {
            if !(2..=MAX_BOARD_SIDE).contains(&n) {
                return Err(bad(
                    name,
                    format!("must be 2 to {MAX_BOARD_SIDE} squares, got {n}"),
                ));
            }
        }
        if self.missing.len() > MAX_MISSING {
            return Err(bad(
                "missing",
                format!(
                    "lists {} cells; at most {MAX_MISSING} may be left out",
                    self.missing.len()
                ),
            ));
        }
        if !(self.square.is_finite() && self.square > 0.0) {
            return Err(bad(
                "square",
                format!("must be a positive length in metres, got {}", self.square),
            ));
        }
        if !(self.pitch.is_finite() && self.pitch > self.square) {
            return Err(bad(
                "pitch",
                format!(
                    "must be more than the square ({}), got {}",
                    self.square, self.pitch
                ),
            ));
        }
        for (k, &(r, c)) in self.missing.iter().enumerate() {
            if r >= self.rows || c >= self.cols {
                return Err(bad(
                    &format!("missing[{k}]"),
                    format!(
                        "cell ({r}, {c}) is outside the {}x{} grid",
                        self.rows, self.cols
                    ),
                ));
            }
        }
        if self.squares().count() < 4 {
            return Err(bad("missing", "leaves fewer than 4 squares".into()));
        }
        Ok(())
    }
}

impl CalibrationPattern {
    /// Every problem of the first bad field, naming it.
    pub fn check(&self) -> Result<(), PatternError> {
        if !(1..=MAX_BOARDS).contains(&self.boards.len()) {
            return Err(PatternError {
                field: "boards".into(),
                message: format!("needs 1 to {MAX_BOARDS} boards, got {}", self.boards.len()),
            });
        }
        for (i, b) in self.boards.iter().enumerate() {
            b.check(i)?;
        }
        Ok(())
    }

    /// Every reference point and its position.
    pub fn reference_points(&self) -> Vec<(CornerId, Point3<f64>)> {
        let mut out = Vec::new();
        for (b, board) in self.boards.iter().enumerate() {
            for (row, col) in board.squares() {
                for (corner, p) in board.corners(row, col).into_iter().enumerate() {
                    let id = CornerId {
                        board: b,
                        row,
                        col,
                        corner,
                    };
                    out.push((id, p));
                }
            }
        }
        out
    }
}

/// White around a printed board, millimetres (room for its label and the scale bar).
const PRINT_MARGIN_MM: f64 = 15.0;

impl GridBoard {
    /// Board `index` as one SVG page at its true size (the document's units are millimetres:
    /// printed at 100 %, without fit-to-page, a square is `square` wide), with a label saying
    /// what it is and where it goes in the pattern frame, and a 100 mm bar to check the print.
    pub fn printable_svg(&self, index: usize) -> String {
        let mm = |m: f64| m * 1000.0;
        let side = |n: u32| mm(f64::from(n - 1) * self.pitch + self.square);
        let (board_w, board_h) = (side(self.cols), side(self.rows));
        let width = (board_w + 2.0 * PRINT_MARGIN_MM).max(100.0 + 2.0 * PRINT_MARGIN_MM);
        let height = board_h + 3.0 * PRINT_MARGIN_MM;
        let mut out = format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width:.3}mm\" height=\"{height:.3}mm\" \
             viewBox=\"0 0 {width:.3} {height:.3}\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n"
        );
        for (r, c) in self.squares() {
            out.push_str(&format!(
                "<rect x=\"{:.3}\" y=\"{:.3}\" width=\"{:.3}\" height=\"{:.3}\" fill=\"black\"/>\n",
                PRINT_MARGIN_MM + mm(f64::from(c) * self.pitch),
                PRINT_MARGIN_MM + mm(f64::from(r) * self.pitch),
                mm(self.square),
                mm(self.square)
            ));
        }
        let text_y = PRINT_MARGIN_MM + board_h + 7.0;
        let v = |a: &Vector3<f64>| format!("({:.3}, {:.3}, {:.3})", a.x, a.y, a.z);
        out.push_str(&format!(
            "<text x=\"{PRINT_MARGIN_MM}\" y=\"{text_y:.3}\" font-family=\"sans-serif\" font-size=\"3\">\
             board {index}: {} x {} squares of {} mm, {} mm apart; print at 100 % (no fit to page): \
             the bar below is 100 mm. Mount with the top-left square's outer corner at {} m, \
             columns along {} and rows along {} (pattern frame).</text>\n",
            self.rows,
            self.cols,
            mm(self.square),
            mm(self.pitch),
            v(&self.origin.coords),
            v(&self.u_axis),
            v(&self.v_axis),
        ));
        let bar_y = text_y + 6.0;
        out.push_str(&format!(
            "<path d=\"M{PRINT_MARGIN_MM} {bar_y:.3} h100 M{PRINT_MARGIN_MM} {:.3} v3 M{:.3} {:.3} v3\" \
             stroke=\"black\" stroke-width=\"0.4\" fill=\"none\"/>\n</svg>\n",
            bar_y - 1.5,
            PRINT_MARGIN_MM + 100.0,
            bar_y - 1.5
        ));
        out
    }
}

impl Default for CalibrationPattern {
    /// The paper's kind of object: two boards at a right angle, so that the reference points
    /// are not coplanar. The pattern frame: z up, the boards' common edge along z at the
    /// origin, one board in the x–z plane (facing −y... seen from y < 0) and one in the y–z
    /// plane; each 6 × 8 squares of 4 cm at 6 cm pitch, with two cells missing in an
    /// asymmetric place.
    fn default() -> Self {
        let board = |u_axis: Vector3<f64>| GridBoard {
            origin: Point3::new(0.0, 0.0, 0.45) + u_axis * 0.02,
            u_axis,
            v_axis: -Vector3::z(),
            rows: 6,
            cols: 8,
            square: 0.04,
            pitch: 0.06,
            missing: vec![(1, 1), (4, 5)],
        };
        CalibrationPattern {
            boards: vec![board(Vector3::x()), board(Vector3::y())],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_board_prints_at_its_true_size_without_its_missing_cells() {
        let p = CalibrationPattern::default();
        let svg = p.boards[0].printable_svg(0);
        // 8 columns of 40 mm squares at 60 mm: 460 mm of board, plus the margins.
        assert!(
            svg.starts_with("<svg ") && svg.contains("width=\"490.000mm\""),
            "{}",
            &svg[..200]
        );
        let squares = svg.matches("fill=\"black\"").count();
        assert_eq!(squares, 6 * 8 - 2);
        assert!(svg.contains("width=\"40.000\" height=\"40.000\""));
        assert!(svg.contains("h100"), "the 100 mm check bar");
        // The missing cell (1, 1) has no square at x = 15 + 60, y = 15 + 60.
        assert!(!svg.contains("x=\"75.000\" y=\"75.000\""));
        assert!(svg.contains("x=\"135.000\" y=\"75.000\""));
    }

    #[test]
    fn the_default_pattern_is_valid_and_not_coplanar() {
        let p = CalibrationPattern::default();
        p.check().unwrap();
        let points = p.reference_points();
        assert_eq!(points.len(), 2 * (6 * 8 - 2) * 4);
        // Not coplanar: some point is off the plane of the first board.
        let n = p.boards[0].normal();
        let o = p.boards[0].origin;
        assert!(points.iter().any(|(_, q)| (q - o).dot(&n).abs() > 0.1));
        // Square corners: side `square`, in order around the square.
        let c = p.boards[1].corners(2, 3);
        assert!(((c[1] - c[0]).norm() - 0.04).abs() < 1e-12);
        assert!(((c[3] - c[0]).norm() - 0.04).abs() < 1e-12);
        assert!((c[2] - c[0]).norm() > 0.05);
    }

    #[test]
    fn bad_boards_name_the_field() {
        let mut p = CalibrationPattern::default();
        p.boards[1].pitch = 0.03;
        assert_eq!(p.check().unwrap_err().field, "boards[1].pitch");
        let mut p = CalibrationPattern::default();
        p.boards[0].u_axis = Vector3::new(1.0, 1.0, 0.0);
        assert_eq!(p.check().unwrap_err().field, "boards[0].u_axis");
        let mut p = CalibrationPattern::default();
        p.boards[0].missing.push((9, 0));
        assert_eq!(p.check().unwrap_err().field, "boards[0].missing[2]");
        assert_eq!(
            CalibrationPattern { boards: vec![] }
                .check()
                .unwrap_err()
                .field,
            "boards"
        );
    }

    #[test]
    fn every_count_of_a_pattern_is_bounded() {
        let huge = |rows: u32, cols: u32| {
            let mut p = CalibrationPattern::default();
            p.boards[1].rows = rows;
            p.boards[1].cols = cols;
            p.check().unwrap_err()
        };
        let e = huge(u32::MAX, u32::MAX);
        assert_eq!(e.field, "boards[1].rows");
        assert!(e.message.len() < 100, "{}", e.message);
        assert_eq!(huge(6, MAX_BOARD_SIDE + 1).field, "boards[1].cols");
        let mut p = CalibrationPattern::default();
        p.boards[0].rows = MAX_BOARD_SIDE;
        p.boards[0].cols = MAX_BOARD_SIDE;
        p.check().unwrap();
        p.boards[0].missing = vec![(0, 0); MAX_MISSING + 1];
        assert_eq!(p.check().unwrap_err().field, "boards[0].missing");
        let p = CalibrationPattern {
            boards: vec![CalibrationPattern::default().boards[0].clone(); MAX_BOARDS + 1],
        };
        assert_eq!(p.check().unwrap_err().field, "boards");
    }
}
