"""Instance-id images of meshes seen by pinhole cameras: one reusable off-screen renderer per process.

Output: ``(v, h, w) uint16``, one image per camera, ``0`` = background, ``k`` = the object whose
instance id is ``k``. Pixel ``(i, j)`` shows the object whose surface is nearest along the ray
through the pixel centre ``(j + 0.5, i + 0.5)`` (the ``sqfit.geometry.camera`` convention).

Backends
--------
``osmesa`` (default), ``egl``
    OpenGL through pyrender's platform layer (``pyrender.platforms``: OSMesa software rendering
    or EGL). Ids are exact: every object is drawn with its id as a constant integer into a
    single-sample ``R32UI`` colour buffer with a depth test, so an edge pixel where two objects
    touch holds the id of the nearer one, never a blend (pyrender's own ``SEG`` flag resolves a
    multisampled buffer and mixes ids at edges). The projection matrix is built directly from the
    OpenCV camera frame (x right, y down, z forward) and the intrinsics: this is the only place
    the OpenCV -> OpenGL conversion happens. Each view renders only inside a scissor box around
    the projected objects and reads back only that box, which makes a 640 x 480 mask cost about a
    millisecond (``benchmarks/bench_render.py``).
``polygon``
    No OpenGL: every object is assumed convex, its mesh vertices are projected with
    ``sqfit.project``, and the convex hull is rasterised with scikit-image. Several objects are
    painted far to near by the depth of their centres, an approximation that is exact unless
    objects interpenetrate or their depth order differs across the silhouette. Vertices behind
    the camera are not supported by this backend (``ValueError``).

OpenGL and processes
--------------------
``PYOPENGL_PLATFORM`` selects the OpenGL binding when ``OpenGL`` is first imported, so one process
can use ``osmesa`` or ``egl``, not both. :func:`get_renderer` sets it (if unset) before importing
OpenGL and creates the context lazily, so call it inside a worker process, never in a parent
before it forks.
"""

from __future__ import annotations

import os
import sys
import threading

import numpy as np

from sqfit import Camera, Intrinsics, project
from sqfit._checks import check_choice
from sqfit.geometry.raster import fill_convex_polygon

__all__ = ["BACKENDS", "Renderer", "GLRenderer", "PolygonRenderer", "get_renderer",
           "projection_matrix", "instance_masks"]

BACKENDS = ("osmesa", "egl", "polygon")

#: Near/far clip planes as fractions of the nearest/farthest vertex depth in each view; the
#: depth buffer only orders surfaces, so a tight range keeps its 24 bits precise.
_NEAR_FRACTION, _FAR_FRACTION = 0.5, 2.0
#: Near plane floor, metres: vertices closer than this to a camera are clipped.
ZNEAR_MIN = 1e-3

_VERTEX_SHADER = """#version 330 core
layout(location = 0) in vec3 position;
layout(location = 1) in uint instance;
uniform mat4 mvp;
flat out uint v_instance;
void main() {
    gl_Position = mvp * vec4(position, 1.0);
    v_instance = instance;
}
"""
_FRAGMENT_SHADER = """#version 330 core
flat in uint v_instance;
layout(location = 0) out uint id;
void main() { id = v_instance; }
"""

_RENDERERS = {}
_RENDERERS_LOCK = threading.Lock()


def get_renderer(backend="osmesa", intrinsics=None):
    """The process-wide renderer for a backend and image size, created on first use.

    Parameters
    ----------
    backend : {"osmesa", "egl", "polygon"}
    intrinsics : sqfit.Intrinsics
        Fixes the image size of the renderer.

    Returns
    -------
    renderer : Renderer

    Raises
    ------
    ValueError
        Unknown backend, or an OpenGL backend other than the one this process already uses.
    OSError
        No off-screen OpenGL context can be created (e.g. libOSMesa missing).
    """
    check_choice(backend, BACKENDS, "renderer backend")
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"intrinsics must be a sqfit.Intrinsics, got {type(intrinsics).__name__}")
    key = (backend, intrinsics)
    with _RENDERERS_LOCK:
        if key not in _RENDERERS:
            _RENDERERS[key] = PolygonRenderer(intrinsics) if backend == "polygon" else GLRenderer(backend, intrinsics)
        return _RENDERERS[key]


class Renderer:
    """Common front end: validation and the (objects, cameras) -> images contract."""

    backend = None

    def __init__(self, intrinsics):
        self.intrinsics = intrinsics

    def render(self, objects, cameras):
        """Instance-id images of objects seen by cameras.

        Parameters
        ----------
        objects : sequence
            Each item is a ``trimesh.Trimesh`` in world coordinates (instance id = its position
            + 1) or has attributes ``mesh`` (``trimesh.Trimesh``) and ``id`` (int in 1..65535),
            and optionally ``outward`` (bool): the mesh is closed with outward-facing triangles,
            which lets OpenGL cull back faces (faster; every object must have it).
        cameras : sequence of sqfit.Camera
            All with this renderer's intrinsics.

        Returns
        -------
        images : (v, h, w) uint16
        """
        meshes, ids, outward = _unpack(objects)
        cameras = list(cameras)
        for k, cam in enumerate(cameras):
            if not isinstance(cam, Camera):
                raise ValueError(f"cameras[{k}] must be a sqfit.Camera, got {type(cam).__name__}")
            if cam.intrinsics != self.intrinsics:
                raise ValueError(f"cameras[{k}] has intrinsics {cam.intrinsics}, but this renderer "
                                 f"was made for {self.intrinsics}")
        k = self.intrinsics
        images = np.zeros((len(cameras), k.height, k.width), dtype=np.uint16)
        if meshes:
            self._render(meshes, ids, outward, cameras, images)
        return images


def _unpack(objects):
    meshes, ids, outward = [], [], []
    for k, obj in enumerate(objects):
        mesh, oid = (obj, k + 1) if hasattr(obj, "faces") else (getattr(obj, "mesh", None), getattr(obj, "id", None))
        if mesh is None or not hasattr(mesh, "faces") or oid is None:
            raise ValueError(f"objects[{k}] must be a trimesh.Trimesh or have 'mesh' and 'id' attributes")
        if int(oid) != oid or not 1 <= oid <= np.iinfo(np.uint16).max:
            raise ValueError(f"objects[{k}].id must be an integer in [1, 65535], got {oid}")
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        if not np.all(np.isfinite(vertices)):
            raise ValueError(f"objects[{k}] mesh has NaN or inf vertices")
        meshes.append(mesh)
        ids.append(int(oid))
        outward.append(bool(getattr(obj, "outward", False)))
    if len(set(ids)) != len(ids):
        raise ValueError(f"object ids must be unique, got {ids}")
    return meshes, ids, outward


def projection_matrix(intrinsics, znear, zfar):
    """OpenGL clip matrix of a pinhole camera, applied to OpenCV camera coordinates.

    Maps ``(x, y, z)`` (x right, y down, z forward) so that after the perspective divide and the
    full-image viewport, window ``x = u`` and window ``y = height - v`` (OpenGL's origin is the
    bottom-left corner, the image's is the top-left), and depth ``z`` in ``[znear, zfar]`` maps
    to NDC ``[-1, 1]``.

    Parameters
    ----------
    intrinsics : sqfit.Intrinsics
    znear, zfar : float
        Clip distances along the optical axis, metres, ``0 < znear < zfar``.

    Returns
    -------
    P : (4, 4) float
    """
    if not 0 < znear < zfar:
        raise ValueError(f"need 0 < znear < zfar, got znear={znear}, zfar={zfar}")
    k = intrinsics
    w, h = k.width, k.height
    return np.array([
        [2 * k.fx / w, 0.0, 2 * k.cx / w - 1, 0.0],
        [0.0, -2 * k.fy / h, 1 - 2 * k.cy / h, 0.0],
        [0.0, 0.0, (zfar + znear) / (zfar - znear), -2 * zfar * znear / (zfar - znear)],
        [0.0, 0.0, 1.0, 0.0],
    ])


def _view_box(intrinsics, pixels, depth):
    """Pixel box ``(i0, i1, j0, j1)`` (half-open) holding every pixel centre the points can cover."""
    front = depth > 0
    if not front.any():
        return None
    if not front.all():  # a vertex behind the camera: the silhouette may reach any pixel
        return 0, intrinsics.height, 0, intrinsics.width
    u, v = pixels[:, 0], pixels[:, 1]
    lo = np.floor(np.array([u.min(), v.min()]) - 0.5).astype(int) - 1
    hi = np.ceil(np.array([u.max(), v.max()]) - 0.5).astype(int) + 2
    j0, i0 = np.maximum(lo, 0)
    j1, i1 = np.minimum(hi, [intrinsics.width, intrinsics.height])
    if j0 >= j1 or i0 >= i1:
        return None
    return int(i0), int(i1), int(j0), int(j1)


class GLRenderer(Renderer):
    """OpenGL instance-id renderer (``osmesa`` or ``egl``), one context, reused for every call."""

    def __init__(self, backend, intrinsics):
        super().__init__(intrinsics)
        check_choice(backend, ("osmesa", "egl"), "OpenGL backend")
        _select_platform(backend)
        self.backend = backend
        self._platform = _make_platform(backend, intrinsics.width, intrinsics.height)
        # One context per renderer: threads of one process (e.g. a Dask worker with several
        # threads) take turns, since an OpenGL context is current in one thread at a time.
        self._lock = threading.Lock()
        self._platform.make_current()
        self._init_gl()

    def _init_gl(self):
        from OpenGL import GL
        from OpenGL.GL import shaders

        w, h = self.intrinsics.width, self.intrinsics.height
        self._program = shaders.compileProgram(
            shaders.compileShader(_VERTEX_SHADER, GL.GL_VERTEX_SHADER),
            shaders.compileShader(_FRAGMENT_SHADER, GL.GL_FRAGMENT_SHADER), validate=False)
        self._mvp = GL.glGetUniformLocation(self._program, "mvp")
        self._fbo = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._fbo)
        color, depth = GL.glGenRenderbuffers(2)
        for rb, fmt, attachment in ((color, GL.GL_R32UI, GL.GL_COLOR_ATTACHMENT0),
                                    (depth, GL.GL_DEPTH_COMPONENT24, GL.GL_DEPTH_ATTACHMENT)):
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, rb)
            GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, fmt, w, h)
            GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, attachment, GL.GL_RENDERBUFFER, rb)
        status = GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER)
        if status != GL.GL_FRAMEBUFFER_COMPLETE:
            raise RuntimeError(f"OpenGL framebuffer incomplete (status {status:#x})")
        self._vao = GL.glGenVertexArrays(1)
        self._buffers = GL.glGenBuffers(3)
        GL.glViewport(0, 0, w, h)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glFrontFace(GL.GL_CCW)
        GL.glCullFace(GL.GL_BACK)
        GL.glDisable(GL.GL_DITHER)
        GL.glEnable(GL.GL_SCISSOR_TEST)
        GL.glUseProgram(self._program)

    def _upload(self, meshes, ids):
        from OpenGL import GL

        vertices = np.concatenate([np.asarray(m.vertices, dtype=np.float32) for m in meshes])
        instance = np.concatenate([np.full(len(m.vertices), i, dtype=np.uint32) for m, i in zip(meshes, ids)])
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        faces = np.concatenate([np.asarray(m.faces) + o for m, o in zip(meshes, offsets)]).astype(np.uint32)
        GL.glBindVertexArray(self._vao)
        vbo, ibo, ebo = self._buffers
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, vbo)
        GL.glBufferData(GL.GL_ARRAY_BUFFER, vertices.nbytes, vertices, GL.GL_STREAM_DRAW)
        GL.glEnableVertexAttribArray(0)
        GL.glVertexAttribPointer(0, 3, GL.GL_FLOAT, GL.GL_FALSE, 0, None)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, ibo)
        GL.glBufferData(GL.GL_ARRAY_BUFFER, instance.nbytes, instance, GL.GL_STREAM_DRAW)
        GL.glEnableVertexAttribArray(1)
        GL.glVertexAttribIPointer(1, 1, GL.GL_UNSIGNED_INT, 0, None)
        GL.glBindBuffer(GL.GL_ELEMENT_ARRAY_BUFFER, ebo)
        GL.glBufferData(GL.GL_ELEMENT_ARRAY_BUFFER, faces.nbytes, faces, GL.GL_STREAM_DRAW)
        return vertices.astype(np.float64), faces.size

    def _render(self, meshes, ids, outward, cameras, images):
        with self._lock:
            self._render_locked(meshes, ids, outward, cameras, images)

    def _render_locked(self, meshes, ids, outward, cameras, images):
        from OpenGL import GL

        self._platform.make_current()
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._fbo)
        GL.glUseProgram(self._program)
        vertices, n_indices = self._upload(meshes, ids)
        # Closed meshes with outward faces: their front faces alone cover the silhouette and hold
        # the nearest depth, so back faces can be culled (half the raster work). A face facing the
        # camera is counter-clockwise in window coordinates with this projection (OpenCV frame is
        # right-handed and window y = -v), OpenGL's default front face.
        if all(outward):
            GL.glEnable(GL.GL_CULL_FACE)
        else:
            GL.glDisable(GL.GL_CULL_FACE)
        h = self.intrinsics.height
        for image, cam in zip(images, cameras):
            pixels, depth = project(cam, vertices)
            box = _view_box(self.intrinsics, pixels, depth)
            if box is None:
                continue
            i0, i1, j0, j1 = box
            front = depth[depth > 0]
            znear = max(_NEAR_FRACTION * front.min(), ZNEAR_MIN)
            P = projection_matrix(self.intrinsics, znear, max(_FAR_FRACTION * front.max(), 2 * znear))
            world_to_camera = np.linalg.inv(cam.pose)
            mvp = np.ascontiguousarray((P @ world_to_camera).T, dtype=np.float32)  # column-major
            GL.glUniformMatrix4fv(self._mvp, 1, GL.GL_FALSE, mvp)
            # The scissor box is in window coordinates (origin bottom-left).
            GL.glScissor(j0, h - i1, j1 - j0, i1 - i0)
            GL.glClearBufferuiv(GL.GL_COLOR, 0, np.zeros(4, dtype=np.uint32))
            GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
            GL.glDrawElements(GL.GL_TRIANGLES, n_indices, GL.GL_UNSIGNED_INT, None)
            out = np.empty((i1 - i0, j1 - j0), dtype=np.uint32)
            GL.glReadPixels(j0, h - i1, j1 - j0, i1 - i0, GL.GL_RED_INTEGER, GL.GL_UNSIGNED_INT, out)
            image[i0:i1, j0:j1] = out[::-1]


def _select_platform(backend):
    """Set ``PYOPENGL_PLATFORM`` for ``backend``, or explain why this process cannot use it."""
    current = os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    if current != backend:
        raise ValueError(f"this process uses PYOPENGL_PLATFORM={current!r}; the {backend!r} "
                         "renderer needs a separate process (OpenGL binds its platform once)")
    platform = sys.modules.get("OpenGL.platform")
    bound = type(getattr(platform, "PLATFORM", None)).__name__.lower() if platform else None
    if bound is not None and backend not in bound:
        raise ValueError(f"OpenGL was imported before PYOPENGL_PLATFORM was set and bound the "
                         f"{bound!r} platform; create the {backend!r} renderer (sqsim.imaging.render.get_renderer) "
                         "before importing OpenGL or pyrender, or set PYOPENGL_PLATFORM in the environment")


def _make_platform(backend, width, height):
    try:
        if backend == "osmesa":
            from pyrender.platforms.osmesa import OSMesaPlatform
            platform = OSMesaPlatform(width, height)
        else:
            from pyrender.platforms import egl
            device = egl.get_device_by_index(int(os.environ.get("EGL_DEVICE_ID", "0")))
            platform = egl.EGLPlatform(width, height, device=device)
        platform.init_context()
    except Exception as exc:  # missing libOSMesa / libEGL surfaces here as many exception types
        raise OSError(f"cannot create an off-screen OpenGL context with the {backend!r} backend "
                           f"({type(exc).__name__}: {exc}); for OSMesa install libosmesa6, or use "
                           "renderer = \"polygon\"") from exc
    return platform


class PolygonRenderer(Renderer):
    """Analytic renderer for convex objects: projected convex hull, rasterised (no OpenGL)."""

    backend = "polygon"

    def _render(self, meshes, ids, outward, cameras, images):
        for image, cam in zip(images, cameras):
            projected = []
            for mesh, oid in zip(meshes, ids):
                pixels, depth = project(cam, np.asarray(mesh.vertices, dtype=np.float64))
                if np.any(depth <= 0):
                    raise ValueError(f"object {oid} reaches behind the camera; the polygon renderer "
                                     "needs every vertex in front of every camera")
                centre_depth = project(cam, np.asarray(mesh.vertices).mean(axis=0, keepdims=True))[1][0]
                projected.append((centre_depth, oid, pixels))
            for _, oid, pixels in sorted(projected, key=lambda t: -t[0]):
                image[polygon_mask(_hull(pixels), image.shape)] = oid


def _hull(pixels):
    from scipy.spatial import ConvexHull

    return pixels[ConvexHull(pixels).vertices]


def polygon_mask(polygon, shape):
    """Pixels whose centres lie inside a convex polygon given in image coordinates.

    See ``sqfit.geometry.raster.fill_convex_polygon`` (exact scanline fill, half-open pixel-centre rule).

    Parameters
    ----------
    polygon : (m, 2) float
        ``(u, v)`` vertices of a convex polygon, image coordinates (``sqfit.geometry.camera`` convention).
    shape : (2,) int
        ``(height, width)``.

    Returns
    -------
    mask : (h, w) bool
    """
    return fill_convex_polygon(polygon, shape)


def instance_masks(image, ids=None):
    """Split an instance-id image into binary masks.

    Parameters
    ----------
    image : (h, w) int
    ids : sequence of int, optional
        Default: the non-zero ids present, sorted.

    Returns
    -------
    masks : dict of int -> (h, w) bool
    """
    image = np.asarray(image)
    if ids is None:
        ids = [int(i) for i in np.unique(image) if i != 0]
    return {int(i): image == i for i in ids}
