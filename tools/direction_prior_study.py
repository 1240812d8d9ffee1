#!/usr/bin/env python3
"""Would a prior on the scene's dominant directions rescue the short segments the gate leaves
out? An experiment, not part of the product (docs/ACCURACY.md, "Tried and dropped").

    python tools/direction_prior_study.py --shared PATH [--bin target/release/trinocular]

Run with a Python that has numpy. For each capture of the rendered rooms it asks the CLI for
everything (`includeUncertain`), finds the capture's dominant 3D directions among its
well-determined segments (direction σ under SIGMAX degrees: greedy modes, each needing MINM
members), estimates the share of segments along none of them, and for each uncertain segment
computes the posterior that it lies along a mode (a Gaussian about the mode against a uniform
direction). Where that posterior reaches PTH, the mode's direction is applied to the segment
as a measurement (a Kalman update of its endpoints under its covariance) and the segment is
kept when its updated position meets the gate's position tolerance (round bound). Prints
error and completeness with and without, scored by the shared scorer, and the classes of the
wrong segments the prior let in. Environment: PTH (0.95), SIGMAX (2), W0MIN (0.05), MINM (5).
What it showed, and why the prior was not kept: docs/ACCURACY.md.
"""
import argparse
import json, os, sys, subprocess, tempfile, numpy as np
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from eval_rooms import request_for, xyz, perp_basis, classify
from concurrent.futures import ThreadPoolExecutor
PTH=float(os.environ.get('PTH','0.95')); SIGMAX=float(os.environ.get('SIGMAX','2')); W0MIN=float(os.environ.get('W0MIN','0.05'))
MINM=int(os.environ.get('MINM','5'))
def run(cdir, images):
    req = request_for(cdir, {"includeUncertain": True}, images)
    f = tempfile.NamedTemporaryFile('w', suffix='.json', delete=False); json.dump(req, f); f.close()
    return json.loads(subprocess.run([BIN, 'match', f.name], check=True, capture_output=True, text=True).stdout)
def seg_arr(s): return np.concatenate([xyz(s['start']), xyz(s['end'])])
def modes(U, W, S2):
    out=[]; W=W.copy()
    for _ in range(4):
        if W.sum()<=0: break
        dots=np.abs(U@U.T)
        tol=np.cos(np.maximum(2.5*np.sqrt(S2)[None,:], np.radians(2)))
        memb=dots>tol
        sup=memb@W
        i=np.argmax(sup); mem=memb[i]&(W>0)
        if mem.sum()<MINM: break
        V=U[mem]*np.sign(U[mem]@U[i])[:,None]; D=(V*W[mem][:,None]).sum(0); D/=np.linalg.norm(D)
        # spread beyond own noise
        ang2=np.arccos(np.clip(np.abs(V@D),0,1))**2
        extra=max(np.average(ang2-S2[mem],weights=W[mem]),0)
        var_mean=1/W[mem].sum()
        out.append((D,extra+var_mean,mem.sum()))
        W=W*(~mem)
    return out
def within(C2, tol, conf=0.95):
    ev=np.linalg.eigvalsh(C2); return 2.45*np.sqrt(ev.max())<=tol
ap = argparse.ArgumentParser()
ap.add_argument("--shared", required=True)
ap.add_argument("--bin", default="target/release/trinocular")
args = ap.parse_args()
BIN = args.bin
sys.path.insert(0, os.path.join(args.shared, "eval"))
import score as S_mod  # noqa: E402
for room in ['office','lab']:
  data=os.path.join(args.shared, 'data', room)
  E = np.asarray(S_mod.load_json(os.path.join(data, "gt_edges.json"))["edges"], float)
  caps=sorted(d[8:] for d in os.listdir(data) if d.startswith('capture_'))
  for images in [True, False]:
    with ThreadPoolExecutor(2) as pool:
        outs=list(pool.map(lambda c: run(os.path.join(data,'capture_'+c), images), caps))
    tot={'base':[0,0,0,0],'snap':[0,0,0,0]}; cls_all=[]
    for cap,out in zip(caps,outs):
        segs=out['segments3d']
        S=np.array([seg_arr(s) for s in segs]).reshape(-1,6)
        unc=np.array([bool(s.get('uncertain')) for s in segs])
        sig=np.radians(np.array([s['directionSigmaDeg'] for s in segs]))
        L=np.linalg.norm(S[:,3:]-S[:,:3],axis=1); U=(S[:,3:]-S[:,:3])/L[:,None]
        sel=sig<np.radians(SIGMAX)
        cl=modes(U[sel], 1/(sig[sel]**2+np.radians(0.3)**2), sig[sel]**2)
        # w0 from the well-determined segments
        good=sig<np.radians(1.0)
        if cl and good.sum():
            far=np.ones(good.sum(),bool)
            for D,v,_ in cl:
                a=np.arccos(np.clip(np.abs(U[good]@D),0,1)); far&= a**2 > 9*(sig[good]**2+v)
            n=good.sum(); w0=max((far.sum()+0.3*5)/(n+5),W0MIN)
        else: w0=1
        shares=np.array([c[2] for c in cl],float)
        if os.environ.get('DBG'): print(cap, sel.sum(), [(np.round(D,2), round(np.degrees(np.sqrt(v)),2), c) for D,v,c in cl], 'w0=%.3f'%w0)
        snapped=[]
        for i,s in enumerate(segs):
            if not unc[i]: snapped.append(S[i]); continue
            if not cl: continue
            u=U[i]; B=perp_basis(u); H=np.hstack([-B,B])/L[i]; C=np.asarray(s['covariance']).reshape(6,6)
            dens=[];upd=[]
            for (D,v,_),wk in zip(cl,(1-w0)*shares/shares.sum()):
                Ds=D*np.sign(D@u); z=B@(Ds-u); R=np.eye(2)*v; Sx=H@C@H.T+R
                dens.append(wk*np.exp(-0.5*z@np.linalg.solve(Sx,z))/(2*np.pi*np.sqrt(np.linalg.det(Sx))))
                K=C@H.T@np.linalg.inv(Sx); upd.append((S[i]+K@z, C-K@H@C))
            dens=np.array(dens); post=dens/(dens.sum()+w0/(2*np.pi))
            k=np.argmax(post)
            if post[k]<PTH: continue
            x,Cn=upd[k]
            # position gate: mid and ends across the line
            m=0.5*(x[:3]+x[3:]); tol=max(0.02,0.01*np.linalg.norm(m)); d=x[3:]-x[:3]; u2=d/np.linalg.norm(d); B2=perp_basis(u2)
            ok=True
            for J in (np.hstack([B2,0*B2]),np.hstack([0*B2,B2]),np.hstack([B2,B2])*0.5):
                if not within(J@Cn@J.T,tol): ok=False
            if ok: snapped.append(x)
        snapped=np.array(snapped).reshape(-1,6)
        pose = S_mod.load_json(os.path.join(data, f"capture_{cap}", "pose.json"))
        T = np.asarray(pose["rig_to_world"], float); c = np.asarray(pose["rig_centre_world"], float)
        sw=np.hstack([snapped[:, :3] @ T[:3, :3].T + T[:3, 3], snapped[:, 3:] @ T[:3, :3].T + T[:3, 3]])
        cls_all+=classify(sw,E,c,S_mod)
        for key,arr in (('base',S[~unc]),('snap',snapped)):
            sc,_=S_mod.score(data,{'segments':arr.tolist(),'frame':'rig'},capture=cap)
            t=tot[key]; t[0]+=sc['n_segments']; t[1]+=sc['n_correct']; t[2]+=sc['eligible_length_m']; t[3]+=sc['covered_length_m']
    for key,t in tot.items():
        print(room, 'images' if images else 'lsd', key, 'n=%d err=%.4f compl=%.4f'%(t[0],1-t[1]/t[0],t[3]/t[2]), flush=True)
    ca=np.array(cls_all); print('   snap classes', {k: int((ca==k).sum()) for k in ('dir_only','pos_near','far')})
