"""FPGA twin diagnostic: the float and fixed-point controllers on the same logged sensors, open
loop: their leg commands before and after the servo's rounding (results/fpga/README.md,
section 1, "What parts: the IK angles"). Run from the repository root; writes under
/tmp/fpgadiag."""
# ruff: noqa: E501   (research script)

import sys
import numpy as np
import jax
import jax.numpy as jnp
from tkujax.control.controller_params import ControllerParams
from tkujax.control.controller import controller_init, controller_step, Sensors
from tkujax.control.cpg import cpg_feet
from tkujax.control.solve import solve_legs
from tkujax.control.fixed import (
                                  FixedPointConfig,
                                  controller_init_fx,
                                  controller_step_fx,
                                  coefficients,
                                  cpg_feet_fx,
                                  to_float,
                                  )


def main() -> None:
    fn = sys.argv[1]
    which = sys.argv[2] if len(sys.argv) > 2 else "fixed"
    D = np.load(fn)
    params = ControllerParams.paper()
    params = __import__("dataclasses").replace(params, control_period=0.03)
    cfg = FixedPointConfig(straight_through=False)
    dt = 0.03


    def run(gyro, accel):
        def body(c, x):
            sf, sx = c
            g, a = x
            nf, of = controller_step(sf, Sensors(g, a), params, 1.0)
            nx, ox = controller_step_fx(sx, Sensors(g, a), params, 1.0, cfg)
            tf = nf.time_s - dt - nf.step_start_s
            pf = jnp.stack(cpg_feet(tf, nf.x_sup_m, params))
            coef = coefficients(params, cfg)
            nt = nx.tick - 1 - nx.step_start_tick
            px = jnp.stack(cpg_feet_fx(nt, nx.x_sup, nx.y_sup, coef, cfg))
            # the float IK applied to the fixed CPG's targets (isolates the IK's error)
            ikf_on_x = solve_legs(*to_float(px, cfg.length), params)[0]
            qf_xsupx = solve_legs(*cpg_feet(tf, to_float(nx.x_sup, cfg.length), params), params)[0]
            return (nf, nx), dict(
                xf=nf.x_sup_m,
                xx=to_float(nx.x_sup, cfg.length),
                pf=pf,
                px=to_float(px, cfg.length),
                qf=of.leg_targets,
                qx=ox.leg_targets,
                qfx=ikf_on_x,
                qfxs=qf_xsupx,
                phif=of.phi,
                phix=ox.phi,
                tf=tf,
                nt=nt,
            )

        return jax.lax.scan(
            body, (controller_init(params), controller_init_fx(params, cfg)), (gyro, accel)
        )[1]


    f = jax.jit(jax.vmap(run))
    R = jax.tree_util.tree_map(
        np.asarray, f(jnp.asarray(D[f"{which}_gyro"]), jnp.asarray(D[f"{which}_accel"]))
    )
    lsb = np.radians(360 / 4096)
    imp, az, ph = D["imp"], D["az"], D["ph"]
    print(
        "per push: max|dphi| mrad, max|dxsup| um, max|dfoot| um, max|dq| mrad (and in servo LSB), IK-only |dq| mrad, n ticks where round() differs, stepping-ticks"
    )
    for i in range(len(imp)):
        st = R["nt"][i] >= 0
        dq = np.abs(R["qf"][i] - R["qx"][i])
        dik = np.abs(R["qfx"][i] - R["qx"][i])
        rf, rx = np.round(R["qf"][i] / lsb), np.round(R["qx"][i] / lsb)
        flips = (rf != rx).any(-1)
        print(
            f"{imp[i]:.1f} az{az[i]:3d} ph{ph[i]} dphi {1e3 * np.abs(R['phif'][i] - R['phix'][i]).max():.4f} dx {1e6 * np.abs(R['xf'][i] - R['xx'][i]).max():6.1f} "
            f"dfoot {1e6 * np.abs(R['pf'][i] - R['px'][i]).max():6.1f} dq {1e3 * dq.max():.4f} ({dq.max() / lsb:.3f} LSB) ik-only {1e3 * dik.max():.4f} flips {flips.sum()} / stepping {st.sum()} "
            f"dq_stand {1e3 * dq[~st].max():.4f} xsup-only {1e3 * np.abs(R['qfxs'][i] - R['qf'][i]).max():.4f}"
        )
    np.savez(fn.replace(".npz", "_open.npz"), **R)


if __name__ == "__main__":
    main()
