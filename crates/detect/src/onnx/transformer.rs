//! The layers DETR-family detectors (RT-DETR) add, on device values: LayerNormalization and
//! GridSample (2D; bilinear and nearest; zeros, border and reflection padding).

use super::args::{axis, expand, Args};
use super::value::{Dev, Val};
use anyhow::{bail, ensure, Result};
use burn::tensor::{Int, Tensor};

/// LayerNormalization (opset 17): `(x - mean) / sqrt(var + epsilon) * scale + bias` over the
/// axes from `axis` to the last, in f32 whatever `stash_type` asks. The optional Mean and
/// InvStdDev outputs (the statistics, shaped as X with the normalised axes at 1) are given too.
pub(crate) fn layer_norm(a: &Args) -> Result<Vec<Val>> {
    let x = a.dev_input(0)?;
    let r = x.rank();
    ensure!(r > 0, "LayerNormalization of a scalar");
    let ax = axis(a.i("axis").unwrap_or(-1), r)?;
    let eps = a.f("epsilon").unwrap_or(1e-5);
    let outer: usize = x.shape[..ax].iter().product();
    let inner: usize = x.shape[ax..].iter().product();
    let t: Tensor<2> = x.t.clone().reshape([outer, inner]);
    let mean = t.clone().mean_dim(1);
    let centred = t - mean.clone();
    let inv = (centred.clone() * centred.clone())
        .mean_dim(1)
        .add_scalar(eps)
        .sqrt()
        .recip();
    let normed = Dev::new(centred * inv.clone(), x.shape.clone())?;
    let scale = a.dev_input(1)?;
    let fits = |p: &Dev, what: &str| {
        ensure!(
            p.rank() <= r
                && p.shape
                    .iter()
                    .rev()
                    .zip(x.shape.iter().rev())
                    .all(|(&q, &d)| q == d || q == 1),
            "{what} of shape {:?} does not broadcast to X {:?}",
            p.shape,
            x.shape
        );
        Ok(())
    };
    fits(&scale, "Scale")?;
    let mut y = normed.t * expand(&scale, &x.shape);
    if let Some(b) = a.opt(2) {
        let b = b.dev(a.dev)?;
        fits(&b, "B")?;
        y = y + expand(&b, &x.shape);
    }
    let mut stat_shape = x.shape.clone();
    stat_shape[ax..].iter_mut().for_each(|d| *d = 1);
    let mut outs = vec![Val::D(Dev {
        t: y,
        shape: x.shape.clone(),
    })];
    if a.n_outputs() > 1 {
        outs.push(Val::D(Dev::new(mean, stat_shape.clone())?));
    }
    if a.n_outputs() > 2 {
        outs.push(Val::D(Dev::new(inv, stat_shape)?));
    }
    Ok(outs)
}

/// `v` reflected into `[lo, hi]` as a triangle wave (onnxruntime's reflection of an
/// out-of-range coordinate, repeated as often as the coordinate is far out).
fn reflect(v: Tensor<3>, lo: f32, hi: f32) -> Tensor<3> {
    let span = hi - lo;
    if span <= 0.0 {
        return v.mul_scalar(0.0).add_scalar(lo);
    }
    let t = v.sub_scalar(lo);
    let period = 2.0 * span;
    let t = t.clone() - t.div_scalar(period).floor().mul_scalar(period);
    t.sub_scalar(span).abs().neg().add_scalar(span + lo)
}

/// GridSample (opset 16 and 20+) of an NCHW input at the `[N, H_out, W_out, 2]` grid's (x, y)
/// positions in [-1, 1]: composed of gathers and products, so the gradient reaches the input
/// and (for linear interpolation) the grid. Modes bilinear/linear and nearest (round half to
/// even, as onnxruntime); padding zeros, border and reflection; both align_corners. Bicubic /
/// cubic and volumetric (5-D) inputs are refused.
pub(crate) fn grid_sample(a: &Args) -> Result<Val> {
    let x = a.dev_input(0)?;
    let g = a.dev_input(1)?;
    ensure!(
        x.rank() == 4,
        "input of shape {:?}: only 2D (NCHW) GridSample is supported",
        x.shape
    );
    let [n, c, h, w] = [x.shape[0], x.shape[1], x.shape[2], x.shape[3]];
    ensure!(
        g.rank() == 4 && g.shape[0] == n && g.shape[3] == 2,
        "grid of shape {:?} for input {:?}: [N, H_out, W_out, 2] expected",
        g.shape,
        x.shape
    );
    let (ho, wo) = (g.shape[1], g.shape[2]);
    let p = ho * wo;
    let mode = a
        .s("mode")
        .unwrap_or(if a.opset >= 20 { "linear" } else { "bilinear" });
    let linear = match mode {
        "bilinear" | "linear" => true,
        "nearest" => false,
        m => bail!("GridSample mode {m} is not supported (linear/bilinear and nearest are)"),
    };
    let padding = a.s("padding_mode").unwrap_or("zeros");
    ensure!(
        matches!(padding, "zeros" | "border" | "reflection"),
        "GridSample padding_mode {padding} is not supported"
    );
    let align = a.i("align_corners").unwrap_or(0) != 0;
    let gt: Tensor<4> = g.t4()?;
    // Pixel coordinates ([N, 1, P]) from the normalised grid.
    let coord = |k: usize, size: usize| -> Tensor<3> {
        let v: Tensor<3> = gt.clone().narrow(3, k, 1).reshape([n, 1, p]);
        let s = size as f32;
        let mut v = if align {
            v.add_scalar(1.0).mul_scalar((s - 1.0) / 2.0)
        } else {
            v.add_scalar(1.0).mul_scalar(s / 2.0).sub_scalar(0.5)
        };
        if !linear {
            v = v.round();
        }
        let (lo, hi) = if align {
            (0.0, s - 1.0)
        } else {
            (-0.5, s - 0.5)
        };
        match padding {
            "border" => v.clamp(0.0, s - 1.0),
            "reflection" => reflect(v, lo, hi),
            _ => v,
        }
    };
    let (px, py) = (coord(0, w), coord(1, h));
    // The corners sampled, each with its weight ([N, 1, P]).
    let corners: Vec<(Tensor<3>, Tensor<3>, Tensor<3>)> = if linear {
        let (x0, y0) = (px.clone().floor(), py.clone().floor());
        let (fx, fy) = (px - x0.clone(), py - y0.clone());
        let (gx, gy) = (
            fx.clone().neg().add_scalar(1.0),
            fy.clone().neg().add_scalar(1.0),
        );
        let (x1, y1) = (x0.clone().add_scalar(1.0), y0.clone().add_scalar(1.0));
        vec![
            (x0.clone(), y0.clone(), gx.clone() * gy.clone()),
            (x1.clone(), y0, fx.clone() * gy),
            (x0, y1.clone(), gx * fy.clone()),
            (x1, y1, fx * fy),
        ]
    } else {
        let one = px.clone().mul_scalar(0.0).add_scalar(1.0);
        vec![(px, py, one)]
    };
    let flat: Tensor<3> = x.t4()?.reshape([n, c, h * w]);
    let (wl, hl) = ((w - 1) as f32, (h - 1) as f32);
    let mut acc: Option<Tensor<3>> = None;
    for (cx, cy, mut wt) in corners {
        if padding == "zeros" {
            let inside = cx
                .clone()
                .greater_equal_elem(0.0)
                .bool_and(cx.clone().lower_equal_elem(wl))
                .bool_and(cy.clone().greater_equal_elem(0.0))
                .bool_and(cy.clone().lower_equal_elem(hl));
            wt = wt * inside.float();
        }
        let idx: Tensor<3, Int> = (cy.clamp(0.0, hl).mul_scalar(w as f32) + cx.clamp(0.0, wl))
            .int()
            .expand([n, c, p]);
        let term = flat.clone().gather(2, idx) * wt.expand([n, c, p]);
        acc = Some(match acc {
            Some(s) => s + term,
            None => term,
        });
    }
    let y = acc.expect("at least one corner");
    Ok(Val::D(Dev::new(y, vec![n, c, ho, wo])?))
}

#[cfg(test)]
mod tests {
    //! What GridSample and ConvTranspose refuse, each error naming what is wrong.
    use super::super::model::{Attr, NodeDef};
    use super::super::ops::eval;
    use super::super::value::{Dev, Val};
    use burn::tensor::{Device, Tensor};

    fn node(op: &str, attrs: &[(&str, Attr)]) -> NodeDef {
        NodeDef {
            name: "n".into(),
            op: op.into(),
            domain: String::new(),
            inputs: vec!["x".into(), "g".into()],
            outputs: vec!["y".into()],
            attrs: attrs
                .iter()
                .map(|(k, v)| (k.to_string(), v.clone()))
                .collect(),
        }
    }

    fn zeros(shape: &[usize], dev: &Device) -> Val {
        let n = shape.iter().product::<usize>();
        Val::D(Dev::new(Tensor::<1>::zeros([n], dev), shape.to_vec()).unwrap())
    }

    fn refusal(op: &str, opset: i64, attrs: &[(&str, Attr)], x: &[usize], g: &[usize]) -> String {
        let dev = Device::from(burn::backend::FlexDevice);
        let (x, g) = (zeros(x, &dev), zeros(g, &dev));
        match eval(&node(op, attrs), opset, &dev, &[Some(&x), Some(&g)]) {
            Ok(_) => panic!("{op} {attrs:?} ran"),
            Err(e) => format!("{e:#}"),
        }
    }

    #[test]
    fn cubic_grid_sampling_and_volumes_are_refused_by_name() {
        let s = |v: &str| Attr::S(v.into());
        let (x, g) = ([1, 2, 4, 4], [1, 3, 3, 2]);
        let e = refusal("GridSample", 16, &[("mode", s("bicubic"))], &x, &g);
        assert!(e.contains("mode bicubic"), "{e}");
        let e = refusal("GridSample", 20, &[("mode", s("cubic"))], &x, &g);
        assert!(e.contains("mode cubic"), "{e}");
        let e = refusal("GridSample", 16, &[("padding_mode", s("wrap"))], &x, &g);
        assert!(e.contains("padding_mode wrap"), "{e}");
        let e = refusal("GridSample", 20, &[], &[1, 2, 3, 4, 4], &[1, 2, 3, 3, 3]);
        assert!(e.contains("only 2D"), "{e}");
        let e = refusal("GridSample", 16, &[], &x, &[1, 3, 3, 3]);
        assert!(e.contains("[N, H_out, W_out, 2]"), "{e}");
    }

    #[test]
    fn conv_transpose_refuses_volumes_and_mismatched_weights() {
        let e = refusal("ConvTranspose", 17, &[], &[1, 2, 3, 4, 4], &[2, 2, 3, 3, 3]);
        assert!(e.contains("only 2D"), "{e}");
        let e = refusal("ConvTranspose", 17, &[], &[1, 4, 5, 5], &[3, 2, 3, 3]);
        assert!(e.contains("does not fit input"), "{e}");
        let e = refusal(
            "ConvTranspose",
            17,
            &[("output_shape", Attr::Is(vec![30, 30]))],
            &[1, 4, 5, 5],
            &[4, 2, 3, 3],
        );
        assert!(e.contains("output_shape [30, 30]"), "{e}");
    }
}
