"""Camera rendering: skipping the hidden skybox and sharing one context between robots change no pixel."""

import mujoco
import numpy as np

from franka_vs_gym.assets.mjcf import TagSpec
from franka_vs_gym.sim import FrankaSim
from franka_vs_gym.sim.rendering import SharedRenderers, render_view, sky_hidden
from franka_vs_gym.vision import CameraIntrinsics, WristCamera

SKYBOX = mujoco.mjtRndFlag.mjRND_SKYBOX


def _with_and_without_sky(r: mujoco.Renderer) -> tuple[np.ndarray, np.ndarray]:
    """The renderer's current scene drawn with the skybox pass and without it."""
    with_sky = r.render()
    r.scene.flags[SKYBOX] = 0
    try:
        return with_sky, r.render()
    finally:
        r.scene.flags[SKYBOX] = 1


def test_skybox_skipped_only_where_it_cannot_show():
    """Free cameras around the table edge, looking down at many angles: whenever sky_hidden says the table covers
    the view, the image drawn without the skybox is the image drawn with it, pixel for pixel; both outcomes occur,
    and where the sky does show (the check said no) the two images differ, so the check is not vacuous."""
    sim = FrankaSim(camera=True, tags=[TagSpec(0, 0.08, (0.55, 0.0, 0.0))])
    m, d = sim.world.model, sim.world.data
    r = sim.world.renderer(64, 48)
    opt, cam = mujoco.MjvOption(), mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    rng = np.random.default_rng(0)
    hidden = shown = 0
    for _ in range(80):
        # the table top spans x in [-0.5, 1.1], y in [-0.8, 0.8] at z = -0.001: look at it and past its +x edge
        cam.lookat[:] = (rng.uniform(0.4, 1.3), rng.uniform(-0.3, 0.3), 0.0)
        cam.distance = rng.uniform(0.2, 0.6)
        cam.azimuth = rng.uniform(0.0, 360.0)
        cam.elevation = rng.uniform(-89.0, -40.0)
        mujoco.mjv_updateScene(m, d, opt, None, cam, mujoco.mjtCatBit.mjCAT_ALL, r.scene)
        with_sky, without = _with_and_without_sky(r)
        if sky_hidden(r.scene, 64, 48):
            hidden += 1
            assert np.array_equal(with_sky, without)
        elif not np.array_equal(with_sky, without):
            shown += 1
    assert hidden >= 10 and shown >= 10, (hidden, shown)


def test_wrist_images_unchanged_by_the_skybox_test():
    """Wrist-camera images of the visual-servoing start views (128x96 and 320x240): render_view skips the skybox
    at every one of them and returns the image drawn with it, pixel for pixel."""
    import gymnasium as gym

    import franka_vs_gym  # noqa: F401

    for w, h in ((128, 96), (320, 240)):
        env = gym.make("FrankaIBVS-v0", observation_type="image", image_width=w, image_height=h).unwrapped
        for seed in range(4):
            env.reset(seed=seed)
            r = env.world.renderer(w, h)
            img = render_view(r, env.world.model, env.world.data, env.sim.camera_name())
            assert sky_hidden(r.scene, w, h)
            with_sky, _ = _with_and_without_sky(r)
            assert np.array_equal(img, with_sky)
            assert img.std() > 5.0
        env.close()


def test_shared_renderer_draws_each_robots_own_image():
    """Three robots in different poses, with randomised link masses (different models, same visual assets): their
    wrist images drawn through one shared context equal those of each robot's own renderer, pixel for pixel; a
    robot looking at another tag (other texture) is refused by the pool and keeps its own renderer."""
    intr = CameraIntrinsics.default(96, 72)
    rng = np.random.default_rng(3)
    sims = []
    for i in range(3):
        s = FrankaSim(camera=True, tags=[TagSpec(0, 0.08, (0.5 + 0.03 * i, 0.02 * i, 0.0))])
        s.set_dynamics(link_mass_scale=rng.uniform(0.8, 1.2, 7))
        s.reset(s.model.robot.neutral() + rng.uniform(-0.1, 0.1, 7))
        sims.append(s)
    own = [WristCamera(s, intr).render() for s in sims]
    pool = SharedRenderers()
    try:
        assert all(s.world.share_renderers(pool) for s in sims)
        shared = [WristCamera(s, intr).render() for s in sims]
        assert len({id(s.world.renderer(96, 72)) for s in sims}) == 1
        for a, b in zip(own, shared, strict=True):
            assert np.array_equal(a, b)
        assert not np.array_equal(own[0], own[1])
        other = FrankaSim(camera=True, tags=[TagSpec(5, 0.08, (0.5, 0.0, 0.0))])
        assert not other.world.share_renderers(pool)
    finally:
        for s in sims:
            s.world.close()
        pool.close()


def test_a_framebuffer_of_the_images_size_draws_the_same_pixels():
    """make_renderer sizes the offscreen framebuffer to the image (less to clear and resolve per frame): the wrist
    and overview images of random arm poses are those of a renderer with the model's 640x480 framebuffer, pixel for
    pixel, at two image sizes; the views differ from pose to pose, so the comparison is not vacuous."""
    from franka_vs_gym.sim.rendering import make_renderer

    sim = FrankaSim(camera=True, tags=[TagSpec(0, 0.08, (0.55, 0.0, 0.0))])
    m, d = sim.world.model, sim.world.data
    assert (m.vis.global_.offwidth, m.vis.global_.offheight) == (640, 480)
    rng = np.random.default_rng(1)
    lim = sim.model.limits()
    for w, h in ((64, 48), (160, 120)):
        small, full = make_renderer(m, w, h), mujoco.Renderer(m, h, w)
        try:
            assert (small.model.vis.global_.offwidth, small.model.vis.global_.offheight) == (w, h)
            images = []
            for _ in range(6):
                sim.joint_views()[0][:] = rng.uniform(0.8 * lim["q_min"], 0.8 * lim["q_max"])
                mujoco.mj_forward(m, d)
                for cam in (sim.camera_name(), -1):
                    a, b = render_view(small, m, d, cam), render_view(full, m, d, cam)
                    assert np.array_equal(a, b), (w, h, cam)
                    images.append(a)
            assert len({im.tobytes() for im in images}) >= 6
        finally:
            small.close()
            full.close()
