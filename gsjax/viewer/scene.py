"""The viewer's scene on a viser server: the Gaussian map as splats, the estimated and ground-truth trajectories
with camera frustums, and a GUI with the run's summary, a frame slider and the input and rendered images of the
selected keyframe.

Everything is in the map's frame (the SLAM world frame: the first camera, OpenCV axes, so "up" is -y). The scene
is fed host snapshots (:class:`MapSnapshot`, :class:`TrajectorySnapshot`) and can be updated while clients are
connected (``gsjax run --viewer``). Images come from a :class:`FrameImages` source, produced in a worker thread so
that neither the server nor the SLAM loop waits for a render.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import io
import math
import socket
import threading
from typing import NamedTuple, Protocol

import numpy as np

from gsjax.camera import rotation_to_quaternion_np
from gsjax.gaussians import Gaussians

ESTIMATE_RGB = (31, 119, 180)
GROUND_TRUTH_RGB = (40, 40, 40)
SELECTED_RGB = (214, 39, 40)
IMAGE_WIDTH = 320  # px: GUI images are enlarged (nearest neighbour) to at least this width
MAP_AS = ("splats", "points")


class MapSnapshot(NamedTuple):
    """The active Gaussians on the host: centers [N, 3] (m), scales [N] (std, m), opacities [N] in (0, 1),
    rgb [N, 3] (clipped to [0, 1] for display)."""

    centers: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    rgb: np.ndarray

    @staticmethod
    def of(gaussians: Gaussians) -> MapSnapshot:
        active = np.asarray(gaussians.active, bool)
        return MapSnapshot(
            centers=np.asarray(gaussians.means, np.float32)[active],
            scales=np.exp(np.asarray(gaussians.log_scales, np.float32)[active]),
            opacities=1.0 / (1.0 + np.exp(-np.asarray(gaussians.logit_opacities, np.float32)[active])),
            rgb=np.clip(np.nan_to_num(np.asarray(gaussians.rgb, np.float32)[active]), 0.0, 1.0),
        )


class TrajectorySnapshot(NamedTuple):
    """Camera poses in the map's frame: ``c2w`` [T, 4, 4] estimated (frames so far); ``gt_frames`` [n] int and
    ``gt_c2w`` [n, 4, 4] the ground truth of those frames (aligned onto the estimate), or None; ``keyframes`` [K]
    int frame numbers."""

    c2w: np.ndarray
    gt_frames: np.ndarray | None
    gt_c2w: np.ndarray | None
    keyframes: np.ndarray


class Camera(NamedTuple):
    """Pinhole intrinsics (px) and image size, for the frustums."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int


class FrameImages(Protocol):
    """Where the selected keyframe's images come from; each returns uint8 [H, W, 3] or None when unavailable."""

    def input_image(self, frame: int) -> np.ndarray | None: ...

    def render_image(self, frame: int) -> np.ndarray | None: ...


def _enlarged(image: np.ndarray) -> np.ndarray:
    zoom = max(1, -(-IMAGE_WIDTH // image.shape[1]))
    return np.ascontiguousarray(np.repeat(np.repeat(image, zoom, axis=0), zoom, axis=1))


def _placeholder(camera: Camera) -> np.ndarray:
    return np.full((camera.height, camera.width, 3), 235, np.uint8)


def check_listen_address(host: str) -> None:
    """ValueError naming ``host`` unless a server can listen there (viser itself would wait forever)."""
    try:
        infos = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        family, kind, proto, _, address = infos[0]
        with socket.socket(family, kind, proto) as probe:
            probe.bind(address)
    except OSError as error:
        raise ValueError(f"the viewer cannot listen on host {host!r} ({error}); use an address of this machine, "
                         "e.g. 127.0.0.1 (the default) or 0.0.0.0 (every interface)") from None


class MapViewer:
    """A viser server showing one run.

    Args:
      camera: the run's camera (frustum shape).
      images: the keyframe images' source.
      title: shown at the top of the GUI panel.
      host, port: where the server listens (port 0: any free port; a busy port: viser tries the next ones).
      map_as: ``"splats"`` or ``"points"`` (the Gaussians' centres), the map's first look; the GUI switches it.
    """

    def __init__(self, camera: Camera, images: FrameImages, title: str = "gsjax", host: str = "127.0.0.1",
                 port: int = 8080, map_as: str = "splats"):
        import viser

        check_listen_address(host)
        with contextlib.redirect_stdout(io.StringIO()):  # viser's banner: gsjax prints the URL itself
            self._server = viser.ViserServer(host=host, port=port, label=title, verbose=False)
        self._camera, self._images = camera, images
        self._lock = threading.Lock()
        self._trajectory: TrajectorySnapshot | None = None
        self._follow = True  # the slider follows the newest frame until the user moves it
        self._worker = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="gsjax-viewer")
        self._pending: concurrent.futures.Future | None = None
        self._shown_key: tuple | None = None
        self._map_version = 0
        scene, gui = self._server.scene, self._server.gui
        scene.set_up_direction("-y")
        self._summary = gui.add_markdown(f"**{title}**")
        self._slider = gui.add_slider("frame", min=0, max=1, step=1, initial_value=0, disabled=True)
        self._keyframe_label = gui.add_markdown("")
        placeholder = _enlarged(_placeholder(camera))
        self._input = gui.add_image(placeholder, label="input", format="png")
        self._render = gui.add_image(placeholder, label="render", format="png")
        with gui.add_folder("Show"):
            self._map_as = gui.add_dropdown(
                "map as", MAP_AS, initial_value=map_as,
                hint="points (the Gaussians' centres) cost a browser far less CPU than splats, whose depth sort runs "
                     "continuously: the choice for a browser on the machine that runs the SLAM")
            self._toggles = {name: gui.add_checkbox(name, True)
                             for name in ("map", "estimate", "ground truth", "keyframes")}
        for name, checkbox in self._toggles.items():
            checkbox.on_update(lambda _, name=name: self._set_visible(name))
        self._map_as_chosen = False  # by a user, in the GUI

        @self._map_as.on_update
        def _(event) -> None:
            self._map_as_chosen |= event.client is not None
            self._show_map()

        self._snapshot: MapSnapshot | None = None

        @self._slider.on_update
        def _(event) -> None:
            if event.client is not None:  # moved by a user, not by an update
                self._follow = int(self._slider.value) == int(self._slider.max)
            self._select(int(self._slider.value))

        self._nodes: dict[str, list] = {name: [] for name in self._toggles}

        @self._server.on_client_connect
        def _(_client) -> None:  # images are made only while someone looks: make the current ones now
            self._select(int(self._slider.value))

    # ------------------------------------------------------------------------------------------ properties

    @property
    def port(self) -> int:
        return self._server.get_port()

    @property
    def url(self) -> str:
        host = self._server.get_host()
        host = "127.0.0.1" if host in ("0.0.0.0", "") else host
        return f"http://{'[' + host + ']' if ':' in host else host}:{self.port}"

    # ------------------------------------------------------------------------------------------ updates

    def set_summary(self, markdown: str) -> None:
        self._summary.content = markdown

    def suggest_map_as(self, map_as: str) -> None:
        """Show the map as ``map_as`` unless a user has chosen in the GUI."""
        if not self._map_as_chosen:
            self._map_as.value = map_as

    def set_map(self, snapshot: MapSnapshot) -> None:
        """Show these Gaussians (replacing the previous map)."""
        with self._lock:
            self._snapshot = snapshot
            self._map_version += 1
            self._shown_key = None  # the render shows the map: redo it
        self._show_map()

    def _show_map(self) -> None:
        with self._lock:
            snapshot = self._snapshot
        if snapshot is None:
            return
        n, scene, visible = len(snapshot.centers), self._server.scene, self._toggles["map"].value
        centers, rgb = snapshot.centers.reshape(n, 3), snapshot.rgb.reshape(n, 3)
        if self._map_as.value == "points":
            size = float(np.median(snapshot.scales)) if n else 0.01  # one std-dev across
            handle = scene.add_point_cloud("/map", points=centers, colors=rgb, point_size=size,
                                           point_shape="circle", visible=visible)
        else:
            covariances = (snapshot.scales.astype(np.float32) ** 2)[:, None, None] * np.eye(3, dtype=np.float32)
            handle = scene.add_gaussian_splats("/map", centers=centers, covariances=covariances.reshape(n, 3, 3),
                                               rgbs=rgb, opacities=snapshot.opacities.reshape(n, 1), visible=visible)
        self._nodes["map"] = [handle]

    def set_trajectory(self, trajectory: TrajectorySnapshot) -> None:
        """Show these trajectories and keyframe frustums; the slider spans their frames."""
        scale = self._frustum_scale(trajectory)
        visible = {name: box.value for name, box in self._toggles.items()}
        self._nodes["estimate"] = [self._path("/trajectory/estimate", trajectory.c2w, ESTIMATE_RGB, scale,
                                              visible["estimate"])]
        self._nodes["ground truth"] = []
        if trajectory.gt_c2w is not None and len(trajectory.gt_c2w) > 1:
            self._nodes["ground truth"].append(self._path("/trajectory/ground_truth", trajectory.gt_c2w,
                                                          GROUND_TRUTH_RGB, scale, visible["ground truth"]))
        frustums = []
        gt_of = ({} if trajectory.gt_frames is None else
                 {int(f): pose for f, pose in zip(trajectory.gt_frames, trajectory.gt_c2w)})
        for frame in trajectory.keyframes:
            frame = int(frame)
            if frame >= len(trajectory.c2w):
                continue
            handle = self._frustum(f"/keyframes/estimate/{frame:06d}", trajectory.c2w[frame], ESTIMATE_RGB, scale,
                                   visible["keyframes"])
            handle.on_click(lambda _, frame=frame: self._jump(frame))
            frustums.append(handle)
            if frame in gt_of:
                frustums.append(self._frustum(f"/keyframes/ground_truth/{frame:06d}", gt_of[frame], GROUND_TRUTH_RGB,
                                              scale, visible["keyframes"] and visible["ground truth"]))
        self._nodes["keyframes"] = frustums
        with self._lock:
            first = self._trajectory is None
            self._trajectory = trajectory
        if first:
            self._set_initial_camera(trajectory, scale)
        last = max(len(trajectory.c2w) - 1, 0)
        self._slider.max = max(last, 1)
        self._slider.disabled = last == 0
        target = last if self._follow or int(self._slider.value) > last else int(self._slider.value)
        if int(self._slider.value) != target:
            self._slider.value = target  # calls _select through on_update
        else:
            self._select(target)

    def stop(self) -> None:
        self._worker.shutdown(wait=False, cancel_futures=True)
        with contextlib.redirect_stdout(io.StringIO()):  # "(viser) Server stopped"; stop() joins the server thread
            self._server.stop()

    # ------------------------------------------------------------------------------------------ internals

    @staticmethod
    def _frustum_scale(trajectory: TrajectorySnapshot) -> float:
        centres = trajectory.c2w[:, :3, 3]
        extent = float(np.max(np.ptp(centres, axis=0))) if len(centres) > 1 else 0.0
        return float(np.clip(0.08 * extent, 0.04, 0.3))

    def _path(self, name: str, c2w: np.ndarray, rgb, scale: float, visible: bool):
        centres = np.asarray(c2w[:, :3, 3], np.float32)
        segments = np.stack([centres[:-1], centres[1:]], axis=1) if len(centres) > 1 else np.zeros((0, 2, 3))
        return self._server.scene.add_line_segments(name, points=segments, colors=rgb, thickness=0.12 * scale,
                                                    visible=visible)

    def _frustum(self, name: str, c2w: np.ndarray, rgb, scale: float, visible: bool, thickness: float = 0.04):
        camera = self._camera
        return self._server.scene.add_camera_frustum(
            name, fov=2.0 * math.atan2(camera.height / 2.0, camera.fy), aspect=camera.width / camera.height,
            scale=scale, thickness=thickness * scale, color=rgb, wxyz=rotation_to_quaternion_np(c2w[:3, :3]),
            position=c2w[:3, 3], visible=visible)

    def _set_initial_camera(self, trajectory: TrajectorySnapshot, scale: float) -> None:
        """Behind and above the first camera, looking at the middle of the trajectory's view."""
        first = trajectory.c2w[0]
        forward, down = first[:3, 2], first[:3, 1]
        target = first[:3, 3] + forward * max(10 * scale, 1.0)
        camera = self._server.initial_camera
        camera.position = first[:3, 3] - forward * 12 * scale - down * 8 * scale
        camera.look_at = target
        camera.up = -down

    def _set_visible(self, name: str) -> None:
        shown = self._toggles[name].value
        for handle in self._nodes[name]:
            handle.visible = shown
        if name == "ground truth":
            for handle in self._nodes["keyframes"]:
                if "/ground_truth/" in handle.name:
                    handle.visible = shown and self._toggles["keyframes"].value

    def _jump(self, frame: int) -> None:
        self._follow = False
        self._slider.value = frame

    def _select(self, frame: int) -> None:
        """Show frame ``frame``'s camera and the images of the keyframe at or before it."""
        with self._lock:
            trajectory = self._trajectory
        if trajectory is None or frame >= len(trajectory.c2w):
            return
        scale = self._frustum_scale(trajectory)
        self._frustum("/selected", trajectory.c2w[frame], SELECTED_RGB, 1.4 * scale, True, thickness=0.08)
        earlier = trajectory.keyframes[trajectory.keyframes <= frame]
        if not len(earlier):
            self._keyframe_label.content = f"frame {frame}: no keyframe yet"
            return
        keyframe = int(earlier.max())
        self._keyframe_label.content = f"frame {frame}; keyframe {keyframe}: its input and the map rendered at its pose"
        if not self._server.get_clients():
            return  # nobody to show them to (a run's live viewer with no browser costs no render)
        with self._lock:
            key = (keyframe, self._map_version)
            if key == self._shown_key:
                return
            self._shown_key = key
            if self._pending is not None:
                self._pending.cancel()
            self._pending = self._worker.submit(self._show_images, keyframe, key)

    def _show_images(self, keyframe: int, key: tuple) -> None:
        for handle, produce, what in ((self._input, self._images.input_image, "input"),
                                      (self._render, self._images.render_image, "render")):
            image = produce(keyframe)
            with self._lock:
                if key != self._shown_key:
                    return  # another keyframe was selected meanwhile
            if image is None:
                handle.label = f"{what}: not stored for keyframe {keyframe}"
                continue
            handle.image = _enlarged(image)
            handle.label = f"{what}, keyframe {keyframe}"
