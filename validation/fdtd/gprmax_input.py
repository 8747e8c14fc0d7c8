"""Scene → gprMax 4 input text (2D TM model), with the grid, domain, time window and a cost estimate.

Rules: dx is the largest of 2.5/2/1.5/1.25/1 mm that divides the trace step and stays ≤ λ/10 in the densest
solid medium at 2.5× the centre frequency (λ/6 inside water, whose echo is the weak inner one); the PML is
gprMax's default 10 cells inside the domain; the domain reaches a margin beyond the line and 6 cm below the
deepest object; the time window is 1.2× the two-way time of the deepest echo plus the source delay and two
periods. Antenna height and Tx–Rx offset are snapped to the grid; the layout reports the snapped values.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

from validation.fdtd.scenes import C_M_PER_NS, Scene

PML_CELLS = 10
DX_CHOICES_UM = (2500, 2000, 1500, 1250, 1000)
EPS_PVC, EPS_WATER, SIGMA_WATER = 3.0, 80.1, 0.05  # water: static permittivity, tap-water conductivity
WATER_EPS_INF, WATER_TAU_S = 4.9, 9.231e-12  # water's Debye pole, as in gprMax's materials.py
EPS_SOIL, SIGMA_SOIL = 15.0, 0.01
LATERAL_MARGIN_M = 0.06
AIR_ABOVE_ANTENNA_M = 0.03
BELOW_DEEPEST_M = 0.06
WINDOW_FACTOR = 1.2
CELLS_PER_SECOND = 6.0e7  # measured: one core of the build machine, 2D TM, single precision (~7e7)
START_SECONDS = 0.4  # per trace: model build and file write


@dataclass(frozen=True)
class Layout:
    """Where everything lands in the gprMax frame, and what the run costs."""

    dx_m: float
    nx: int
    ny: int
    surface_y_m: float
    first_mid_x_m: float  # gprMax x of trace 0's antenna midpoint (the truth frame's x = 0)
    height_m: float
    offset_m: float
    time_window_ns: float
    dt_ns: float
    iterations: int
    source_peak_ns: float
    rule_note: str

    def estimate_s(self, traces: int) -> float:
        """Estimated seconds on one core for the whole B-scan."""
        return traces * (self.nx * self.ny * self.iterations / CELLS_PER_SECOND + START_SECONDS)


def _snap(value: float, dx: float) -> float:
    return round(value / dx) * dx


def grid_step_m(scene: Scene) -> tuple[float, str]:
    """The cell size for a scene and a note when the λ/10 rule could not be met."""
    f_hi = 2.5 * scene.frequency_mhz * 1e6
    eps_solid = [scene.concrete.eps_max(), EPS_PVC] + [s.eps_r for s in scene.stones]
    if scene.slab_bottom_m is not None and scene.below == "soil":
        eps_solid.append(EPS_SOIL)
    need = C_M_PER_NS * 1e9 / f_hi / math.sqrt(max(eps_solid)) / 10.0
    if any(p.fill == "pvc-water" for p in scene.pipes):
        need = min(need, C_M_PER_NS * 1e9 / f_hi / math.sqrt(EPS_WATER) / 6.0)
    step_um = round(scene.step_m * 1e6)
    for dx_um in DX_CHOICES_UM:
        if dx_um <= need * 1e6 + 1e-6 and step_um % dx_um == 0:
            return dx_um * 1e-6, ""
    return DX_CHOICES_UM[-1] * 1e-6, f"grid rule wants {need * 1e3:.2f} mm; using 1 mm"


def deepest_echo_ns(scene: Scene) -> float:
    """Two-way time (below the surface, straight down) of the latest echo the window must hold."""
    v = scene.velocity_m_per_ns()
    times = [2.0 * (r.depth_m + r.radius_m) / v for r in scene.rebars]
    times += [2.0 * (s.depth_m + s.radius_m) / v for s in scene.stones]
    for p in scene.pipes:
        t = 2.0 * (p.depth_m + p.radius_m) / v
        if p.fill == "pvc-water":
            inner = p.radius_m - p.wall_m
            t = 2.0 * (p.depth_m - p.radius_m) / v + 4.0 * inner * math.sqrt(EPS_WATER) / C_M_PER_NS
        times.append(t)
    if scene.slab_bottom_m is not None:
        times.append(2.0 * scene.slab_bottom_m / v)
    return max(times, default=2.0 * 0.15 / v)


def layout(scene: Scene) -> Layout:
    """The grid, domain and time window of a scene (see the module docstring for the rules)."""
    dx, note = grid_step_m(scene)
    pml = PML_CELLS * dx
    height, offset = _snap(scene.height_m, dx), _snap(scene.offset_m, 2 * dx)
    objects = [p.depth_m + p.radius_m for p in scene.pipes] + [r.depth_m + r.radius_m for r in scene.rebars]
    objects += [s.depth_m + s.radius_m for s in scene.stones] + [0.1]
    below = max(objects) + BELOW_DEEPEST_M
    if scene.slab_bottom_m is not None:
        below = max(below, scene.slab_bottom_m + BELOW_DEEPEST_M)
    surface_y = _snap(pml + below, dx)
    ny = round((surface_y + height + AIR_ABOVE_ANTENNA_M + pml) / dx)
    first_mid = _snap(pml + LATERAL_MARGIN_M + offset / 2, dx)
    nx = round((first_mid + scene.length_m + offset / 2 + LATERAL_MARGIN_M + pml) / dx)
    f_ghz = scene.frequency_mhz / 1000.0
    peak = math.sqrt(2.0) / f_ghz  # gprMax's Ricker peaks at chi = sqrt(2) / f
    air = 2.0 * math.hypot(height, offset / 2) / C_M_PER_NS
    window = WINDOW_FACTOR * (peak + air + deepest_echo_ns(scene) + 2.0 / f_ghz)
    dt = dx / (C_M_PER_NS * 1e9 * math.sqrt(2.0)) * 1e9  # 2D CFL limit, as gprMax sets it
    return Layout(dx, nx, ny, surface_y, first_mid, height, offset, round(window, 3), dt,
                  math.ceil(window / dt), peak, note)


def _fmt(value: float) -> str:
    return f"{value:.6g}"


def input_text(scene: Scene) -> str:
    """The gprMax input file of a scene's B-scan (run it with -n scene.traces)."""
    lay = layout(scene)
    dx = lay.dx_m
    X, Y, ys = lay.nx * dx, lay.ny * dx, lay.surface_y_m
    f = scene.frequency_mhz
    c = scene.concrete
    lines = [
        f"#title: gprbot validation scene {scene.name} ({scene.kind}, {f:g} MHz)",
        "#domain_mode: TM",
        f"#domain: {_fmt(X)} {_fmt(Y)} inf",
        f"#dx_dy_dz: {_fmt(dx)} {_fmt(dx)} {_fmt(dx)}",
        f"#time_window: {_fmt(lay.time_window_ns * 1e-9)}",
        f"#material: {_fmt(c.eps_r)} {_fmt(c.sigma_s_per_m)} 1 0 concrete",
    ]
    fills = {p.fill for p in scene.pipes}  # only materials in use: gprMax checks the grid against every one
    if fills & {"pvc-air", "pvc-water"}:
        lines.append(f"#material: {EPS_PVC:g} 0 1 0 pvc")
    if "pvc-water" in fills:  # single-pole Debye water (gprMax's own constants) plus tap-water ionic loss
        lines.append(f"#material: {WATER_EPS_INF:g} {SIGMA_WATER:g} 1 0 water")
        lines.append(f"#add_dispersion_debye: 1 {EPS_WATER - WATER_EPS_INF:g} {WATER_TAU_S:g} water")
    if scene.slab_bottom_m is not None and scene.below == "soil":
        lines.append(f"#material: {EPS_SOIL:g} {SIGMA_SOIL:g} 1 0 soil")
    if c.debye is not None:
        lines.append(f"#add_dispersion_debye: 1 {_fmt(c.debye[0])} {_fmt(c.debye[1])} concrete")
    stone_eps = sorted({round(s.eps_r * 2) / 2 for s in scene.stones})
    lines += [f"#material: {e:g} 0 1 0 stone{i}" for i, e in enumerate(stone_eps)]
    ant_y = ys + lay.height_m
    tx = lay.first_mid_x_m - lay.offset_m / 2
    lines += [
        f"#waveform: ricker 1 {_fmt(f * 1e6)} src",
        f"#hertzian_dipole: z {_fmt(tx)} {_fmt(ant_y)} inf src",
        f"#rx: {_fmt(tx + lay.offset_m)} {_fmt(ant_y)} inf",
        f"#src_steps: {_fmt(scene.step_m)} 0 0",
        f"#rx_steps: {_fmt(scene.step_m)} 0 0",
    ]
    bottom_y = 0.0 if scene.slab_bottom_m is None else ys - scene.slab_bottom_m
    lines.append(f"#box: 0 {_fmt(bottom_y)} 0 {_fmt(X)} {_fmt(ys)} inf concrete")
    if scene.slab_bottom_m is not None and scene.below == "soil":
        lines.append(f"#box: 0 0 0 {_fmt(X)} {_fmt(bottom_y)} inf soil")

    def circle(x: float, depth: float, r: float, material: str) -> str:
        gx, gy = lay.first_mid_x_m + x, ys - depth
        return f"#cylinder: {_fmt(gx)} {_fmt(gy)} 0 {_fmt(gx)} {_fmt(gy)} inf {_fmt(r)} {material}"

    for s in scene.stones:
        lines.append(circle(s.x_m, s.depth_m, s.radius_m, f"stone{stone_eps.index(round(s.eps_r * 2) / 2)}"))
    lines += [circle(r.x_m, r.depth_m, r.radius_m, "pec") for r in scene.rebars]
    for p in scene.pipes:
        if p.fill == "metal":
            lines.append(circle(p.x_m, p.depth_m, p.radius_m, "pec"))
        else:  # a PVC shell: the outer cylinder in PVC, the bore (air or water) cut into it
            lines.append(circle(p.x_m, p.depth_m, p.radius_m, "pvc"))
            bore = "free_space" if p.fill == "pvc-air" else "water"
            lines.append(circle(p.x_m, p.depth_m, p.radius_m - p.wall_m, bore))
    return "\n".join(lines) + "\n"


def in_sha256(text: str) -> str:
    """The hash that names a run's cache folder and goes into the truth JSON."""
    return hashlib.sha256(text.encode()).hexdigest()


def describe(scene: Scene) -> str:
    """One line: grid, cells, iterations, traces and the estimated cost."""
    lay = layout(scene)
    note = f"; {lay.rule_note}" if lay.rule_note else ""
    return (f"{scene.name}: dx {lay.dx_m * 1e3:g} mm, {lay.nx}x{lay.ny} cells, {lay.iterations} iterations, "
            f"{scene.traces} traces -> ~{lay.estimate_s(scene.traces):.0f} s on one core{note}")
