"""How much energy each integrator takes out of a swinging cloth on its own.

The default scene's cloth (``hang_two_corners``: 1 m, held by two corner patches,
released from horizontal) on a uniform mesh, with nothing else that takes energy
out: no air (``air.density=0``), no material damping, no isotropic drag, both pins
held still (no release, no waypoints: they do no work), no LOD (a merge changes the
energy).  The total energy E = kinetic + gravity + stretch + shear + bend (J) is then
conserved by the equations of motion, and whatever an integrator loses is its own
numerical dissipation.  The loss is reported as a fraction of the energy the swing
can lose at all, ``(E(0) − E(T)) / (E(0) − E_rest)``, with ``E_rest`` the energy of
the cloth hanging at rest (the same scene with heavy damping, run to rest).

Run ``python -m cloth_lod_ros.tools.dissipation`` for the table in docs/model.md
("Numerical dissipation").
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

__all__ = ["swing_overrides", "swing", "total_energy", "energy_loss", "rest_energy", "TABLEAUS",
           "damping_per_step", "main"]


def _tableaus() -> dict:
    """Butcher tableaus ``(A, b)`` of the schemes here and of the candidates weighed
    against them (Hairer & Wanner, *Solving ODEs II*, §IV.6; TR-BDF2: Hosea & Shampine
    1996, as a three-stage ESDIRK; SDIRK3: Alexander 1977, L-stable, stiffly accurate)."""
    g = 1.0 - 1.0 / np.sqrt(2.0)
    tr = 2.0 - np.sqrt(2.0)
    w = np.sqrt(2.0) / 4.0
    a = 0.435866521508459
    b1, b2 = -(6 * a * a - 16 * a + 1) / 4, (6 * a * a - 20 * a + 5) / 4
    return {
        "backward_euler": (np.array([[1.0]]), np.array([1.0])),
        "sdirk2": (np.array([[g, 0.0], [1.0 - g, g]]), np.array([1.0 - g, g])),
        "tr_bdf2": (np.array([[0.0, 0.0, 0.0], [tr / 2, tr / 2, 0.0], [w, w, tr / 2]]),
                    np.array([w, w, tr / 2])),
        "sdirk3": (np.array([[a, 0.0, 0.0], [(1 - a) / 2, a, 0.0], [b1, b2, a]]),
                   np.array([b1, b2, a])),
        "midpoint": (np.array([[0.5]]), np.array([1.0])),
    }


#: name -> (A, b) of the Runge-Kutta schemes compared in docs/model.md.
TABLEAUS = _tableaus()


def damping_per_step(name: str, omega_h: float) -> float:
    """Fraction of an undamped oscillation's amplitude a scheme removes per step,
    ``1 − |R(iωh)|`` with ``R(z) = 1 + z bᵀ (I − zA)⁻¹ 1`` its stability function."""
    A, b = TABLEAUS[name]
    z = 1j * omega_h
    r = 1.0 + z * (b @ np.linalg.solve(np.eye(len(b)) - z * A, np.ones(len(b))))
    return float(1.0 - abs(r))

_PINS = ("[{name: top_left, uv: [0.0, 1.0], radius: 0.0625}, "
         "{name: top_right, uv: [1.0, 1.0], radius: 0.0625}]")


def swing_overrides(level: int, integrator: str, time_step: float | None = None,
                    error_tolerance: float | None = None, duration: float = 10.0) -> list:
    """``--set`` overrides of ``hang_two_corners`` for the undamped swing."""
    out = ["lod.enabled=false", f"cloth.level={level}", "air.density=0",
           "material.stretch_damping=0", "material.shear_damping=0",
           "material.bend_damping=0", "material.air_drag=0", f"pins={_PINS}",
           f"simulation.integrator={integrator}", f"simulation.duration={duration}"]
    if time_step is not None:
        out.append(f"simulation.time_step={time_step!r}")
    if error_tolerance is not None:
        out.append(f"simulation.error_tolerance={error_tolerance!r}")
    return out


def total_energy(sim) -> float:
    """Kinetic + gravity + elastic energy of the current state, J."""
    return float(sum(sim.energy().values()))


def rest_energy(level: int) -> float:
    """Energy (J) of the swing's cloth hanging at rest: the same scene with strong
    isotropic drag, run by backward Euler until its kinetic energy is below 1e-6 J
    (the swing starts with about 0.9 J above rest: the table's percentages do not see
    the difference)."""
    from ..sim import ClothSim
    # A direct solve: an iterative one's residual keeps the cloth trembling above it.
    sim = ClothSim.from_scene("hang_two_corners", swing_overrides(level, "backward_euler") + [
        "material.air_drag=4", "simulation.error_tolerance=0", "solver.method=direct",
        "simulation.newton_iterations=4"])
    while sim.time < 60.0:
        sim.step()
        if sim.time > 5.0 and sim.energy()["kinetic"] < 1e-6:
            return total_energy(sim)
    raise RuntimeError(f"the damped swing is not at rest after 60 s (kinetic energy "
                       f"{sim.energy()['kinetic']:.3g} J)")


def swing(level: int, integrator: str, duration: float = 10.0,
          time_step: float | None = None, error_tolerance: float | None = None,
          extra: list | tuple = ()):
    """The undamped swing's :class:`~cloth_lod_ros.sim.ClothSim`.  ``integrator``: a
    ``simulation.integrator`` or a study scheme of
    :data:`~cloth_lod_ros.sim.integrate.schemes.STUDY_SCHEMES` (``midpoint``), which
    replaces sdirk2's scheme under the same step control.  ``extra``: more overrides."""
    from ..sim import ClothSim
    from ..sim.integrate.schemes import STUDY_SCHEMES
    study = STUDY_SCHEMES.get(integrator)
    sim = ClothSim.from_scene("hang_two_corners", swing_overrides(
        level, "sdirk2" if study else integrator, time_step, error_tolerance,
        duration) + list(extra))
    if study is not None:
        simulation = sim.scene.simulation
        sim.stepper.scheme = study(simulation.newton_iterations, simulation.newton_tolerance,
                                   sim.scene.contact.max_correction_speed)
    return sim


def energy_loss(level: int, integrator: str, duration: float = 10.0,
                time_step: float | None = None, error_tolerance: float | None = None,
                e_rest: float | None = None, extra: list | tuple = ()) -> dict:
    """Run the undamped swing (:func:`swing`); its energy trace and loss.

    Returns a dict: ``times`` and ``energy`` ``(frames + 1,)`` (s, J), ``lost`` the
    fraction ``(E(0) − E(T)) / (E(0) − E_rest)``, ``cpu`` the process CPU seconds of
    the run, ``substeps`` the steps the error control took.
    """
    if e_rest is None:
        e_rest = rest_energy(level)
    sim = swing(level, integrator, duration, time_step, error_tolerance, extra)
    times, energy = [sim.time], [total_energy(sim)]
    substeps = 0
    start = time.process_time()
    while sim.time < duration - 1e-9:
        stats = sim.step()
        substeps += stats.substeps
        times.append(sim.time)
        energy.append(total_energy(sim))
        if not abs(energy[-1] - energy[0]) < 100.0 * abs(energy[0] - e_rest):
            break                        # blown up: report how far it got
    cpu = time.process_time() - start
    energy = np.array(energy)
    return dict(times=np.array(times), energy=energy, e_rest=e_rest, end=sim.time,
                lost=float((energy[0] - energy[-1]) / (energy[0] - e_rest)),
                cpu=cpu, substeps=substeps)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--level", type=int, default=6, help="uniform mesh level (6: 33 x 33)")
    parser.add_argument("--duration", type=float, default=10.0, help="s simulated")
    parser.add_argument("--integrators", nargs="+",
                        default=["sdirk2", "backward_euler", "baraff_witkin"],
                        help="simulation.integrator values, or midpoint (a study scheme)")
    parser.add_argument("--steps", type=float, nargs="*", default=[1 / 60, 1 / 120, 1 / 240],
                        help="fixed steps h (s) to run besides the default step control")
    parser.add_argument("--newton", type=int, default=None,
                        help="Newton iterations per stage (default: the scene's, 1), "
                             "with tolerance 1e-8 m when given")
    parser.add_argument("--stability", action="store_true",
                        help="print each scheme's damping per step of a linear oscillation")
    args = parser.parse_args(argv)
    if args.stability:
        values = (0.1, 0.3, 1.0, 3.0, 10.0)
        print("scheme         | " + " | ".join(f"wh = {y:g}" for y in values))
        for name in TABLEAUS:
            print(f"{name:14s} | " + " | ".join(f"{damping_per_step(name, y):8.2e}"
                                                  for y in values))
        return
    extra = [] if args.newton is None else [f"simulation.newton_iterations={args.newton}",
                                            "simulation.newton_tolerance=1e-8"]
    e_rest = rest_energy(args.level)
    print(f"level {args.level}, {args.duration:g} s, E_rest = {e_rest:.6g} J, "
          f"load {os.getloadavg()[0]:.1f}")
    print("integrator      | step control            | lost by T/2 | lost by T | substeps | CPU s")
    for integrator in args.integrators:
        runs = [("default", None, None)] + [(f"fixed h = 1/{round(1 / h)} s", h, 0.0)
                                             for h in args.steps]
        for label, h, tol in runs:
            r = energy_loss(args.level, integrator, args.duration, h, tol, e_rest, extra)
            if r["end"] < args.duration - 1e-9:
                print(f"{integrator:15s} | {label:23s} | blew up at t = {r['end']:.2f} s "
                      f"(energy x{r['energy'][-1] / r['energy'][0]:.3g}) | "
                      f"{r['substeps']:8d} | {r['cpu']:5.1f}", flush=True)
                continue
            half = np.searchsorted(r["times"], 0.5 * args.duration)
            lost_half = (r["energy"][0] - r["energy"][half]) / (r["energy"][0] - e_rest)
            print(f"{integrator:15s} | {label:23s} | {100 * lost_half:10.1f}% | "
                  f"{100 * r['lost']:8.1f}% | {r['substeps']:8d} | {r['cpu']:5.1f}",
                  flush=True)


if __name__ == "__main__":
    main()
