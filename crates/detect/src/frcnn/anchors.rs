//! torchvision's `AnchorGenerator`: rounded zero-centred cell anchors per level (aspect ratio
//! major, then size), shifted over the feature grid (row major, then anchor) by the stride
//! `padded_size / grid_size` (integer division).

/// Cell anchors `[x1, y1, x2, y2]` of one level.
pub(crate) fn cell_anchors(sizes: &[f32], ratios: &[f32]) -> Vec<[f32; 4]> {
    let mut out = Vec::new();
    for &r in ratios {
        let hr = r.sqrt();
        let wr = 1.0 / hr;
        for &s in sizes {
            let (ws, hs) = (wr * s, hr * s);
            out.push([-ws / 2.0, -hs / 2.0, ws / 2.0, hs / 2.0].map(f32::round_ties_even));
        }
    }
    out
}

/// All anchors of one level over a `(gh, gw)` grid of the `(ph, pw)` padded input.
pub(crate) fn grid_anchors(
    cell: &[[f32; 4]],
    grid: (usize, usize),
    padded: (usize, usize),
) -> Vec<[f32; 4]> {
    let (sy, sx) = (padded.0 / grid.0, padded.1 / grid.1);
    let mut out = Vec::with_capacity(grid.0 * grid.1 * cell.len());
    for y in 0..grid.0 {
        for x in 0..grid.1 {
            let (dx, dy) = ((x * sx) as f32, (y * sy) as f32);
            for a in cell {
                out.push([dx + a[0], dy + a[1], dx + a[2], dy + a[3]]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_anchors_match_torchvision() {
        // torchvision: AnchorGenerator(((32,),), ((0.5, 1.0, 2.0),)).cell_anchors[0]
        let a = cell_anchors(&[32.0], &[0.5, 1.0, 2.0]);
        assert_eq!(
            a,
            vec![
                [-23.0, -11.0, 23.0, 11.0],
                [-16.0, -16.0, 16.0, 16.0],
                [-11.0, -23.0, 11.0, 23.0]
            ]
        );
        let g = grid_anchors(&a[1..2], (2, 2), (64, 64));
        assert_eq!(g[3], [16.0, 16.0, 48.0, 48.0]);
    }
}
