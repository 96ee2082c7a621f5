import time, json, sys, numpy as np
from splitrender.scene.builtin import Scene, PathMotion
from splitrender.client import play
from splitrender.net.model import NetworkModel
from splitrender.types import ReprojectOptions, Camera
from splitrender.evaluation.metrics import psnr, ssim, vmaf, evaluate_sequence
from splitrender.reproject import reproject_alpha

FS, FC = 10.0, 120.0
_cache = {}
def scene(name, variant="dynamic"):
    k = (name, variant)
    if k not in _cache: _cache[k] = Scene(name, variant)
    return _cache[k]

def server_frames(name, variant, scale, delay=0.1, n=11, subframes=4):
    sc = scene(name, variant); m = PathMotion(sc, delay)
    return [sc.server_frame(k, scale, FS, subframes, pose=m.server_pose(k, FS), samples=1) for k in range(n)]

def gt(name, variant, scale, n_client=120, toff=0.0, delay=0.1):
    sc = scene(name, variant); m = PathMotion(sc, delay)
    cams, imgs = [], []
    for n in range(n_client):
        t = n / FC
        (cam, img), = sc.client_frames(n, scale, FC, pose=m.client_pose(t), samples=1)
        if toff != 0.0:
            img = sc.ground_truth(cam, t + toff, samples=1)
        cams.append(cam); imgs.append(img)
    return cams, imgs

def run(frames, cams, method="ours", **opts):
    o = ReprojectOptions(**opts)
    res = play(frames, cams, NetworkModel(client_fps=FC), FC, method, options=o)
    return res

def score(imgs, truth, use_vmaf=False, skip=12):
    ms = ("ssim", "psnr", "vmaf") if use_vmaf else ("ssim", "psnr")
    sm = evaluate_sequence(imgs, truth, skip, ms, fps=FC)
    return sm
