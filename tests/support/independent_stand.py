"""An independent stand simulator for testing the diagnosis (numpy and the standard library).

Written apart from plant/ and analysis/records/synthetic.py (by a separate session that had not read
them), with effect laws that differ from the catalogue's where a real stand might: a reversal
timed from the undelayed command, a sensor lag, backlash, a power-law flow, friction, an
oscillation with its own phase in every run. tests/test_diagnose_independent.py checks what
`stand diagnose` makes of them.

Plant:  dy/dt = g * q(t) * (effect factors) + delta  [- leak*y] [- friction]
        q(t)  = flow from the delayed, zero-order-held command u(t - tau)
Fine Euler step H = 0.1 ms (20 sub-steps per 2 ms sample). The command is computed / given
once per 2 ms sample and held. Delay is realised on the fine grid (tau rounded to 0.1 ms).
Measurement (sampled at the start of each 2 ms sample, before the command of that sample is
computed):  y_meas = quantize(y_sensor + oscillation + N(0, sigma^2), 0.5 kgf).
Closed loops (relay, P-feedback) see y_meas.

One hidden effect per simulation (or "none"), or several joined by "+":
  rev_cmd    boost 1 + B*exp(-s/Tr) on the flow, s = time since the last sign change of the
             UNDELAYED command u(t) (sign change = new nonzero sign differs from last nonzero sign)
  rev_flow   same law, s = time since the last sign change of the delayed flow q
  rev_force  boost 1 + B*exp(-|y - y_rev|/F) on the flow, decaying with the force travelled since
             the last sign change of the delayed flow (y_rev: the force then), F = 150 kgf
  lag        first-order valve lag after the delay, T = 15 ms
  deadzone   command dead zone (shifted): u -> sign(u)*max(0, |u| - 1 %)
  saturation flow clipped at +-12 %
  asymmetry  negative flow x 0.8
  loadpress  flow * sqrt(max(0, 1 - sign(q)*y/Fs)), Fs = 12000 kgf (y = true force)
  leakage    - lambda*y, lambda = 0.1 1/s
  sensorlag  dynamometer first-order lag 10 ms (noise added after the lag)
  backlash   +-0.5 % play (backlash) on the command: x = clip(x, u-0.5, u+0.5)
  flownl     q = sign(u) * 10 * (|u|/10)^0.8
  osc        20 kgf * sin(2*pi*3 Hz*t + phase) added to the measurement
  friction   |dy/dt| from the flow reduced by 100 kgf/s (never reversing it) when |q| > 0
  stiffening specimen stiffness rising with the load: rate x (1 + k*|y|/1e4), k = 1.5
  valve2nd   second-order valve after the delay: natural frequency 25 Hz, damping 0.5
  gaindrift  flow gain drifting over each run (oil warming): g x (1 + a*t), a = 0.01 1/s
  softload   a specimen 15 % softer while loading (the flow drives |y| up) than unloading, switching at
             zero force: rate x 0.85 when sign(q) = sign(y)
  dirdelay   the command reaches the valve 35 ms after it steps up and 70 ms after it steps down
             (each change of the held command is applied after its own delay, in order; replaces tau)
  dirlatch   the valve follows a rising command 35 ms late and a falling one 70 ms late, the
             earlier one first (no queue: a fall that reaches it before the rise before it ends
             the rise): it sits at the highest command that reached it within the fall's
             extra 35 ms (replaces tau). Under steps it is dirdelay; under a smooth command
             dirdelay's queue holds a rise back behind the falls still in it
  slew       the spool moves at most 400 %/s (a rate limit after the delay, instead of a lag)
  res        second-order valve/actuator after the delay: 6 Hz, damping 0.2 (rings)
  supply     supply pressure sags with the flow drawn: dps/dt = (1 - ps)/T - c*|q|/100, flow x
             sqrt(ps), T = 1 s, c = 1.5 (ps relative, 1 at rest)
  jitter     the delay varies at random, 0-4 ms more at each 2 ms sample (controller/bus timing)
  nulldrift  the valve's null drifts as it warms over each run: the spool sits b*t off the
             command, b = 0.005 %/s (t since the run began)
  forcelimit a relief valve: the force cannot rise above Fmax = 1500 kgf (it stays there, noise
             on top, while the flow pushes; it leaves as soon as the flow turns)
  stiction   rod seal friction: the specimen's force is a play of total width w = 200 kgf on the
             hydraulic force (the rod sticks after each reversal until the pressure has
             changed by w); the dynamometer measures the specimen's force
  lostmotion lost motion in the rod's travel: a play of total width b = 1.5 %*s between the
             piston and the rod, in the flow's travel (the flow passed, command % x s); after
             each reversal the piston travels b before the rod (and the force) follows. The
             trend and the leak act on the specimen's force, after the play (stiction's play
             sits on the hydraulic force, before them)
  supripple  the supply pressure oscillates, and the flow with it: flow x (1 + a*sin(2*pi*f*t +
             phase)), a = 0.15, f = 3 Hz, t since the run began (phase as for osc); no
             catalogue effect has this law (docs/your-own-effect.md writes it as a plug-in)
"""
from __future__ import annotations

import math

import numpy as np

H = 1e-4
TS = 2e-3
SUB = int(round(TS / H))

DEFAULTS = dict(g=118.0, tau=0.0517, delta=6.0, sigma=2.0, res=0.5)

EFFECT_PARAMS = {
    "none": {},
    "rev_cmd": dict(boost=2.0, decay=0.15),
    "rev_flow": dict(boost=2.0, decay=0.15),
    "lag": dict(T=0.015),
    "deadzone": dict(d=1.0),
    "saturation": dict(qmax=12.0),
    "asymmetry": dict(neg=0.8),
    "loadpress": dict(Fs=12000.0),
    "leakage": dict(lam=0.1),
    "sensorlag": dict(T=0.010),
    "backlash": dict(band=0.5),
    "flownl": dict(ref=10.0, p=0.8),
    "osc": dict(A=20.0, f=3.0),
    "friction": dict(F=100.0),
    "stiffening": dict(k=1.5),
    "valve2nd": dict(f=25.0, zeta=0.5),
    "gaindrift": dict(a=0.01),
    "stiction": dict(w=200.0),
    "softload": dict(soft=0.15),
    "dirdelay": dict(up=0.035, down=0.070),
    "dirlatch": dict(up=0.035, down=0.070),
    "slew": dict(rate=400.0),
    "res": dict(f=6.0, zeta=0.2),
    "supply": dict(T=1.0, c=1.5),
    "jitter": dict(j=0.004),
    "nulldrift": dict(b=0.005),
    "rev_force": dict(boost=2.0, F=150.0),
    "forcelimit": dict(Fmax=1500.0),
    "supripple": dict(a=0.15, f=3.0),
    "lostmotion": dict(b=1.5),
}


def _sgn(x: float) -> int:
    return 1 if x > 0 else (-1 if x < 0 else 0)


class _Reversals:
    """Time of the last sign change (a new non-zero sign that differs from the last one)."""

    def __init__(self) -> None:
        self.last = 0
        self.at = -1e9

    def see(self, x: float, t: float) -> None:
        s = _sgn(x)
        if s != 0:
            if self.last != 0 and s != self.last:
                self.at = t
            self.last = s


def simulate(n: int, controller, effect: str = "none", y0: float = 0.0, rng=None,
             plant: dict | None = None, osc_phase: float = 0.0, values: dict | None = None):
    """Simulate n samples. controller(k, t, y_meas) -> (u, r). Returns t, u, y_meas, r, y_true.

    ``effect``: one name of EFFECT_PARAMS, or several joined by "+" (applied together, each in
    its place along the chain). ``values``: an effect's parameters other than EFFECT_PARAMS's
    (``{"lag": {"T": 0.03}}``)."""
    p = dict(DEFAULTS)
    if plant:
        p.update(plant)
    es = set(effect.split("+")) - {"none"}
    unknown = es - set(EFFECT_PARAMS)
    if unknown:
        raise ValueError(f"unknown effect(s) {sorted(unknown)}")
    P = {name: {**EFFECT_PARAMS[name], **(values or {}).get(name, {})} for name in es}
    rng = rng or np.random.default_rng(0)
    g, delta = p["g"], p["delta"]
    D = int(round(p["tau"] / H))           # delay in fine steps
    sigma, res = p["sigma"], p["res"]
    noise = rng.normal(0.0, sigma, n)

    t_out = np.arange(n) * TS
    u_out = np.zeros(n)
    r_out = np.full(n, np.nan)
    ym_out = np.zeros(n)
    yt_out = np.zeros(n)
    ucmd = [0.0] * n                       # command after command-side effects (before delay)
    applied = []                           # dirdelay: (fine step it reaches the valve, value)
    last_apply = 0
    valve_in = 0.0
    xs = 0.0                               # slew: spool position
    xp = xr = 0.0                          # lostmotion: the piston's and the rod's travel, %*s
    ps = 1.0                               # supply: relative supply pressure
    jit = rng.integers(0, int(round(P.get("jitter", {}).get("j", 0.0) / H)) + 1, n)

    y = float(y0)
    yp = float(y0)                         # stiction: the specimen's force (a play on y)
    ys = float(y0)                         # sensor state
    qv = 0.0                               # valve lag state
    qd = 0.0                               # second-order valve: rate of the spool
    bl = 0.0                               # backlash output
    cmd_rev = _Reversals()                 # of the undelayed command
    flow_rev = _Reversals()                # of the delayed flow
    force_rev = _Reversals()               # rev_force: of the delayed flow, with the force then
    y_rev = None
    two_pi_f = 2 * math.pi * P.get("osc", {}).get("f", 0.0)

    for k in range(n):
        tk = k * TS
        # --- measurement at t_k
        meas = ys if "sensorlag" in es else (yp if "stiction" in es else y)
        if "osc" in es:
            meas += P["osc"]["A"] * math.sin(two_pi_f * tk + osc_phase)
        meas += noise[k]
        meas = round(meas / res) * res
        ym_out[k] = meas
        yt_out[k] = y
        # --- controller
        u, r = controller(k, tk, meas)
        u = max(-100.0, min(100.0, float(u)))
        u_out[k] = u
        r_out[k] = r
        uc = u
        if "backlash" in es:
            b = P["backlash"]["band"]
            bl = min(max(bl, uc - b), uc + b)
            uc = bl
        if "dirdelay" in es:
            prev = ucmd[k - 1] if k else 0.0
            if uc != prev:
                dly = P["dirdelay"]["up"] if uc > prev else P["dirdelay"]["down"]
                at = max(k * SUB + int(round(dly / H)), last_apply)
                applied.append((at, uc))
                last_apply = at
        ucmd[k] = uc
        if "rev_cmd" in es:
            cmd_rev.see(u, tk)
        # --- fine steps over [t_k, t_k + TS)
        base_i = k * SUB
        for j in range(SUB):
            i = base_i + j
            t = i * H
            di = i - D - (int(jit[k]) if "jitter" in es else 0)
            v = ucmd[di // SUB] if di >= 0 else 0.0
            if "dirdelay" in es:
                while applied and applied[0][0] <= i:
                    valve_in = applied.pop(0)[1]
                v = valve_in
            if "dirlatch" in es:         # the extreme that reached the valve in the extra delay
                dl = P["dirlatch"]
                first = i - int(round(min(dl["up"], dl["down"]) / H))
                spread = int(round(abs(dl["down"] - dl["up"]) / H))
                held = ucmd[max(first - spread, 0) // SUB:first // SUB + 1] if first >= 0 else [0.0]
                v = (max if dl["down"] > dl["up"] else min)(held)
            if "nulldrift" in es:
                v += P["nulldrift"]["b"] * t
            # valve chain
            if "deadzone" in es:
                a = abs(v) - P["deadzone"]["d"]
                v = math.copysign(a, v) if a > 0 else 0.0
            if "flownl" in es:
                fp = P["flownl"]
                v = math.copysign(fp["ref"] * (abs(v) / fp["ref"]) ** fp["p"], v) if v != 0 else 0.0
            if "lag" in es:
                qv += H / P["lag"]["T"] * (v - qv)
                q = qv
            elif "valve2nd" in es or "res" in es:
                v2 = P["valve2nd"] if "valve2nd" in es else P["res"]
                wn = 2 * math.pi * v2["f"]
                qd += H * (wn * wn * (v - qv) - 2 * v2["zeta"] * wn * qd)
                qv += H * qd
                q = qv
            elif "slew" in es:
                st = P["slew"]["rate"] * H
                xs += min(max(v - xs, -st), st)
                q = xs
            else:
                q = v
            if "saturation" in es:
                q = max(-P["saturation"]["qmax"], min(P["saturation"]["qmax"], q))
            if "supply" in es:
                sp = P["supply"]
                ps += H * ((1.0 - ps) / sp["T"] - sp["c"] * abs(q) / 100.0)
                q *= math.sqrt(max(ps, 0.0))
            if "supripple" in es:
                sr = P["supripple"]
                q *= 1.0 + sr["a"] * math.sin(2 * math.pi * sr["f"] * t + osc_phase)
            if "asymmetry" in es and q < 0:
                q *= P["asymmetry"]["neg"]
            if "loadpress" in es:
                q *= math.sqrt(max(0.0, 1.0 - _sgn(q) * y / P["loadpress"]["Fs"]))
            if "rev_cmd" in es:
                rp = P["rev_cmd"]
                q *= 1.0 + rp["boost"] * math.exp(-(t - cmd_rev.at) / rp["decay"])
            if "rev_flow" in es:
                rp = P["rev_flow"]
                flow_rev.see(q, t)
                q *= 1.0 + rp["boost"] * math.exp(-(t - flow_rev.at) / rp["decay"])
            if "rev_force" in es:
                at = force_rev.at
                force_rev.see(q, t)
                if force_rev.at != at:
                    y_rev = y
                if y_rev is not None:
                    rp = P["rev_force"]
                    q *= 1.0 + rp["boost"] * math.exp(-abs(y - y_rev) / rp["F"])
            if "lostmotion" in es:       # the rod follows the piston through the play
                half = P["lostmotion"]["b"] / 2
                xp += H * q
                moved = min(max(xr, xp - half), xp + half) - xr
                xr += moved
                q = moved / H
            rate = g * q
            if "stiffening" in es:
                rate *= 1.0 + P["stiffening"]["k"] * abs(y) / 1e4
            if "softload" in es and q != 0.0 and _sgn(q) == _sgn(y):
                rate *= 1.0 - P["softload"]["soft"]
            if "gaindrift" in es:
                rate *= 1.0 + P["gaindrift"]["a"] * t
            if "friction" in es and q != 0.0:
                m = abs(rate) - P["friction"]["F"]
                rate = math.copysign(m, rate) if m > 0 else 0.0
            rate += delta
            if "leakage" in es:
                rate -= P["leakage"]["lam"] * y
            y += H * rate
            if "forcelimit" in es:
                y = min(y, P["forcelimit"]["Fmax"])
            if "stiction" in es:
                half = P["stiction"]["w"] / 2
                yp = min(max(yp, y - half), y + half)
            if "sensorlag" in es:
                ys += H / P["sensorlag"]["T"] * (y - ys)
    return t_out, u_out, ym_out, r_out, yt_out


# ---------------------------------------------------------------- experiments

def meander(u0: float, half_period: float = 2.0, cycles: int = 4, hold: float = 0.5):
    """Open loop: hold 0 for `hold` s, +u0 for a quarter period, then alternate every half period."""
    n = int(round((hold + half_period / 2 + cycles * 2 * half_period) / TS))
    u = np.zeros(n)
    t = np.arange(n) * TS
    tt = t - hold
    on = tt >= 0
    # quarter period of +u0, then alternating half periods
    seg = np.floor((tt + half_period / 2) / half_period).astype(int)
    u[on] = u0 * np.where(seg[on] % 2 == 0, 1.0, -1.0)

    def ctl(k, tk, ym):
        return u[k], math.nan
    return n, ctl


def relay(u0: float, ref: float, duration: float):
    n = int(round(duration / TS))

    def ctl(k, tk, ym):
        e = ref - ym
        return (u0 if e > 0 else -u0 if e < 0 else 0.0), ref
    return n, ctl


def pfeedback(kp: float, amp: float, freq: float, duration: float):
    n = int(round(duration / TS))
    w = 2 * math.pi * freq

    def ctl(k, tk, ym):
        r = amp * math.sin(w * tk)
        return kp * (r - ym), r
    return n, ctl


PLAN = [
    # (name, kind, args, y0)
    ("meander_u5", "meander", dict(u0=5.0), 0.0),
    ("meander_u10", "meander", dict(u0=10.0), 0.0),
    ("meander_u15", "meander", dict(u0=15.0), 0.0),
    ("meander_u20", "meander", dict(u0=20.0), 0.0),
    ("relay_r0", "relay", dict(u0=10.0, ref=0.0, duration=20.0), -300.0),
    ("relay_r2000", "relay", dict(u0=10.0, ref=2000.0, duration=20.0), 1500.0),
    ("pfb_f0.5", "pfeedback", dict(kp=0.005, amp=2000.0, freq=0.5, duration=30.0), 0.0),
    ("pfb_f1.5", "pfeedback", dict(kp=0.005, amp=2000.0, freq=1.5, duration=30.0), 0.0),
]


def make_dataset(effect: str, seed: int, fixed_phase: float | None = None, plan=None,
                 plant: dict | None = None, values: dict | None = None):
    """All runs of one data set: list of (name, kind, t, u, y_meas, r, y_true). ``plan``: the
    runs (default :data:`PLAN`); ``plant``, ``values``: as :func:`simulate` takes them. The
    noise of a run depends only on ``seed`` and the runs before it, not on the effects."""
    rng = np.random.default_rng(seed)
    out = []
    for name, kind, args, y0 in PLAN if plan is None else plan:
        n, ctl = {"meander": meander, "relay": relay, "pfeedback": pfeedback}[kind](**args)
        phase = float(rng.uniform(0, 2 * math.pi))
        if fixed_phase is not None:
            phase = fixed_phase
        t, u, ym, r, yt = simulate(n, ctl, effect=effect, y0=y0, rng=rng, osc_phase=phase,
                                   plant=plant, values=values)
        out.append((name, kind, t, u, ym, r, yt))
    return out
