from lib import *
import numpy as np
for name in ["courtyard"]:
    fr = server_frames(name, "dynamic", 0.125, n=3)
    sc = scene(name)
    for k in (0,1):
        f = fr[k]
        g = sc.ground_truth(f.main.camera, f.time, samples=1)
        d = np.abs(g.astype(int) - f.main.color.astype(int))
        print(name, k, "GT(server cam, t_k) vs server colour: max", d.max(), "psnr", psnr(g, f.main.color) if d.max() else "inf")
    # ours at alpha=0 at F0's camera
    for a, cam_k in ((0.0, 0), (0.5, 0), (1.0, 1)):
        out = reproject_alpha(fr[0], fr[1], fr[cam_k].main.camera, a, "ours")
        ref = fr[cam_k].main.color
        d = np.abs(out.astype(int) - ref.astype(int))
        print(f"ours alpha={a} at F{cam_k} camera vs F{cam_k} colour: max {d.max()} mean {d.mean():.3f} frac>8 {(d.max(-1)>8).mean():.4f} psnr {psnr(out, ref):.2f} ssim {ssim(out, ref):.4f}")
    # alpha=0.5: GT at F0 cam at t=0.05
    g = sc.ground_truth(fr[0].main.camera, 0.05, samples=1)
    out = reproject_alpha(fr[0], fr[1], fr[0].main.camera, 0.5, "ours")
    print("ours a=0.5 F0 cam vs GT(F0 cam, 0.05):", psnr(out, g), ssim(out, g))
