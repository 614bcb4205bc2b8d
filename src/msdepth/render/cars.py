"""Cars: a painted body with lights and plate, a cabin with windshields and side glass, wheels."""

from __future__ import annotations

from typing import Any

import numpy as np

from msdepth.render.scene import (
    GLASS,
    GLASS_IOR,
    PAINT,
    TYRE,
    Roi,
    Scene,
    box_planes,
    place,
    yaw_matrix,
)

_CAR_COLOURS = [
    (0.85, 0.85, 0.85),
    (0.6, 0.62, 0.65),
    (0.08, 0.08, 0.09),
    (0.55, 0.06, 0.05),
    (0.08, 0.15, 0.45),
    (0.25, 0.27, 0.3),
    (0.7, 0.7, 0.62),
    (0.1, 0.3, 0.15),
]


# The default street's cars: 0-6 of them, their centres 4-40 m ahead.
CAR_COUNT, CAR_DEPTH = (0, 6), (4.0, 40.0)
# A street's cars: (min, max) count and (min, max) metres ahead of their centres.
CarRanges = tuple[tuple[int, int], tuple[float, float]]


def add_cars(
    scene: Scene,
    rng: np.random.Generator,
    sides: dict,
    road: dict,
    count: tuple[int, int] = CAR_COUNT,
    depth: tuple[float, float] = CAR_DEPTH,
) -> None:
    """``count`` (min, max) cars, parked at the kerb or in a lane, their centres ``depth`` (min, max)
    metres ahead: body, cabin with windshields and side glass, wheels. The defaults draw exactly
    what the renderer always drew."""
    u = rng.uniform
    cam_h = scene.cam_height
    placed: list[tuple[float, float, float, float]] = []
    lane_centres = np.concatenate([[road["left"]], road["lines"]]) + 0.5 * (
        np.diff(np.concatenate([[road["left"]], road["lines"], [road["right"]]]))
    )
    instance = 0
    for _ in range(int(rng.integers(count[0], count[1] + 1))):
        for _attempt in range(20):
            length, width = u(3.8, 4.9), u(1.65, 1.95)
            if rng.random() < 0.5:
                s = int(rng.choice([-1, 1]))
                x = sides[s]["edge"] - s * (width / 2 + u(0.2, 0.5))
                yaw = np.radians(u(-5, 5)) + (np.pi if rng.random() < 0.5 else 0.0)
            else:
                x = float(rng.choice(lane_centres)) + u(-0.4, 0.4)
                yaw = np.radians(u(-4, 4)) + (np.pi if x < -1.5 and rng.random() < 0.7 else 0.0)
            zc = u(*depth)
            near = zc - length / 2
            if abs(x) < width / 2 + 1.2 and near < 5:
                continue  # nothing sits on top of the camera car
            fp = (x - width / 2 - 0.4, x + width / 2 + 0.4, zc - length / 2 - 0.5, zc + length / 2 + 0.5)
            if any(fp[0] < q[1] and q[0] < fp[1] and fp[2] < q[3] and q[2] < fp[3] for q in placed):
                continue
            placed.append(fp)
            instance += 1
            _add_car(scene, rng, instance, np.array([x, cam_h, zc]), yaw, length, width)
            break


def _add_car(
    scene: Scene,
    rng: np.random.Generator,
    instance: int,
    pos: np.ndarray,
    yaw: float,
    length: float,
    width: float,
) -> None:
    """One car at ``pos`` (centre on the ground) heading ``yaw``; registers its ROIs."""
    u = rng.uniform
    rot = yaw_matrix(yaw)
    paint = np.array(_CAR_COLOURS[int(rng.integers(len(_CAR_COLOURS)))]) * u(0.85, 1.1)
    tint = np.array([0.03, 0.035, 0.04]) * u(0.7, 2.0)
    # (index of refraction, interior depth m); one draw each, as many as ever (docs/glass.md)
    glass_prm = (u(*GLASS_IOR), u(0.8, 1.6))
    clear, top = u(0.22, 0.3), u(0.85, 1.05)
    roof = top + u(0.42, 0.58)
    half_l = length / 2
    base_front, base_back = half_l * u(0.45, 0.6), -half_l * u(0.55, 0.75)
    roof_front, roof_back = base_front - u(0.6, 1.0), base_back + u(0.3, 0.7)

    def faces(material: int, extra: tuple = ()) -> dict[str, Any]:
        prm = glass_prm if material == GLASS else extra
        return dict(
            material=material,
            origin=pos,
            colour=tint if material == GLASS else paint,
            params=prm,
            instance=instance,
        )

    # Lower body (paint) with lights on the front/back faces (params[0]: 1 front, 2 back).
    n, c, k = box_planes(np.array([-width / 2, -top, -half_l]), np.array([width / 2, -clear, half_l]))
    args = [faces(PAINT, (1.0 if nl[2] > 0.5 else 2.0 if nl[2] < -0.5 else 0.0, width / 2)) for nl in n]
    n, c, k = place(n, c, k, rot, pos)
    body_corners = k
    car_faces = scene.add_polytope(n, c, k, args)

    cabin = _cabin_planes(width / 2 - 0.08, top, roof, (base_front, roof_front), (base_back, roof_back))
    n, c, k = place(*cabin, rot, pos)
    ids = scene.add_polytope(n, c, k, [faces(m) for m in (PAINT, PAINT, GLASS, GLASS, GLASS, GLASS)])
    car_faces += ids
    quad = {2: k[[4, 5, 6, 7]], 3: k[[0, 1, 2, 3]], 4: k[[0, 1, 4, 5]], 5: k[[2, 3, 6, 7]]}
    for local, cls in ((2, "glass"), (3, "glass"), (4, "windshield"), (5, "windshield")):
        scene.rois.append(Roi(cls, np.array([ids[local]]), quad[local]))

    wheel_ids, wheel_corners = _add_wheels(scene, rng, instance, pos, rot, (half_l, width, clear))
    corners = np.concatenate([body_corners, k, *wheel_corners])
    scene.rois.append(Roi("car", np.array(car_faces + wheel_ids), corners))


def _cabin_planes(
    w2: float, top: float, roof: float, front: tuple[float, float], back: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cabin in the car's frame (half width ``w2``, from height ``top`` to ``roof``): a prism
    whose front and back faces are the tilted windshield and rear window, each running from
    ``z_base`` at ``top`` to ``z_roof`` at the roof (``front``, ``back``: ``(z_base, z_roof)``)."""

    def tilted(z_base: float, z_roof: float, sign: float) -> tuple[np.ndarray, float]:
        normal = np.array([0.0, -sign * (z_base - z_roof), sign * (roof - top)])
        normal /= np.linalg.norm(normal)
        return normal, float(normal @ np.array([0.0, -top, z_base]))

    (base_front, roof_front), (base_back, roof_back) = front, back
    nf, cf = tilted(base_front, roof_front, 1.0)
    nb, cb = tilted(base_back, roof_back, -1.0)
    n = np.array([[0, 1, 0], [0, -1, 0], [1, 0, 0], [-1, 0, 0], nf, nb], float)
    c = np.array([-top + 0.02, roof, w2, w2, cf, cb])
    k = np.array(
        [
            [x, -yy, zz]
            for x in (-w2, w2)
            for yy, zz in ((top, base_front), (roof, roof_front), (top, base_back), (roof, roof_back))
        ]
    )
    return n, c, k


def _add_wheels(
    scene: Scene,
    rng: np.random.Generator,
    instance: int,
    pos: np.ndarray,
    rot: np.ndarray,
    size: tuple[float, float, float],
) -> tuple[list[int], list[np.ndarray]]:
    """One dark box per axle, standing on the ground (part of the car's box), for a car of half
    length, width and ground clearance ``size``; returns their face ids and corners."""
    u = rng.uniform
    half_l, width, clear = size
    ids, corners = [], []
    for zc in (half_l - u(0.75, 0.95), -half_l + u(0.75, 0.95)):
        r = u(0.3, 0.36)
        n, c, k = box_planes(
            np.array([-width / 2 + 0.03, -(clear + 0.2), zc - r]), np.array([width / 2 - 0.03, 0.0, zc + r])
        )
        args = [dict(material=TYRE, origin=pos, colour=(0.05, 0.05, 0.055), instance=instance) for _ in n]
        n, c, k = place(n, c, k, rot, pos)
        ids += scene.add_polytope(n, c, k, args)
        corners.append(k)
    return ids, corners
