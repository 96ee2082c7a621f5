import pickle, numpy as np
from PIL import Image
d = pickle.load(open("base_courtyard_0.125.pkl", "rb"))
n = 54; im, g = d["imgs"][n], d["truth"][n]
print("alpha", d["info"][n].alpha)
err = np.abs(im.astype(int) - g.astype(int)).max(-1)
e = np.clip(err * 4, 0, 255).astype(np.uint8)
row = np.concatenate([g, im, np.stack([e]*3, -1)], 1)
Image.fromarray(row.astype(np.uint8)).save("courtyard_n54_gt_ours_err.png")
# error by pixel class: fraction of total squared error on high-gradient (texture) pixels
gy = g.astype(float).mean(-1); gr = np.hypot(*np.gradient(gy))
print("mean abs err", err.mean(), "pixels err>32:", (err>32).mean())
