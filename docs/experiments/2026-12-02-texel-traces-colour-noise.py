#!/usr/bin/env python3
"""Study prototype (docs/experiments/2026-12-02-texel-traces.md): is a colour map's fine residual
correlated across R, G and B (a texture's grain) or not (noise added per channel)? Each material's
base colour: 512² crop, box-filtered ÷4 in linear light, as 8-bit sRGB; clean and with Gaussian
noise of σ 3 levels; the flattest tenth of its 16×16 patches (by the green channel's Immerkær
response), their σ and their mean correlation of the three channel pairs' responses.

    python docs/experiments/2026-12-02-texel-traces-colour-noise.py ../shared/materials ../shared/corpus
"""
import glob
import os
import sys

import numpy as np
from PIL import Image
from scipy.signal import convolve2d
K=np.array([[1,-2,1],[-2,4,-2],[1,-2,1]],float)
def lin(v): return np.where(v<=0.04045, v/12.92, ((v+0.055)/1.055)**2.4)
def srgb(v): return np.where(v<=0.0031308, v*12.92, 1.055*np.power(np.clip(v,0,None),1/2.4)-0.055)
def load(folder):
    p=os.path.join(folder,'baseColor.png')
    a=np.asarray(Image.open(p).convert('RGB')).astype(float)/255
    a=lin(a)[:512,:512]
    h,w=a.shape[:2]; h-=h%4; w-=w%4
    a=a[:h,:w].reshape(h//4,4,w//4,4,3).mean(axis=(1,3))
    return np.round(srgb(a)*255)
def reading(img):
    r=[convolve2d(img[:,:,c],K,mode='valid') for c in range(3)]
    n=r[0].shape[0]//16
    pat=[]
    for py in range(n):
        for px in range(n):
            sl=(slice(py*16,py*16+16),slice(px*16,px*16+16))
            s=np.mean(np.abs(r[1][sl]))
            x=[r[c][sl].flatten() for c in range(3)]
            cc=np.mean([np.corrcoef(x[a],x[b])[0,1] for a,b in [(0,1),(1,2),(0,2)]])
            pat.append((s,cc))
    pat.sort()
    flat=pat[:max(4,len(pat)//10)]
    return np.median([p[0] for p in flat])*np.sqrt(np.pi/2)/6, np.nanmedian([p[1] for p in flat])
rng=np.random.default_rng(0)
folders=[f for s in sys.argv[1:] for f in sorted(glob.glob(os.path.join(s,'*/')))]
for f in folders:
    if not os.path.exists(os.path.join(f,'baseColor.png')): continue
    img=load(f)
    noisy=np.clip(np.round(img+rng.normal(0,3,img.shape)),0,255)
    s0,c0=reading(img); s3,c3=reading(noisy)
    print(f"{os.path.basename(f.rstrip('/'))[:30]:30} clean σ {s0:5.2f} corr {c0:5.2f} | noise3 σ {s3:5.2f} corr {c3:5.2f}")
