#!/usr/bin/env python3
"""The MARS state policy trained in PyTorch: the peer `mars bench-train` times ours against.

Written from the paper (sections 3-4, Table S1) and PyTorch's own modules, not translated from our Rust: a
state-MLP encoder, the modal scheduler w = sigmoid(MLP(obs_emb)), the source a0 = (1 - w) * history + w * eps,
a DiT velocity field (adaLN-Zero, tokens = the chunk's steps), and L_fm + lambda_rec * L_rec + lambda_div * L_div,
AdamW with weight decay on the matrices only. Same sizes and the same training samples as ours: `mars
bench-train` writes them (samples.safetensors: obs, history, next, neighbours, s_next) with the config
(config.json), runs this script with `torch.set_num_threads(threads)`, and reads one JSON line per epoch
({"epoch": i, "seconds": s, "loss": l}) from its stdout.

    python torch_trainer.py DIR --kind mars --epochs 2 --threads 1
"""

import argparse
import json
import math
import time

import torch
import torch.nn.functional as F
from safetensors.torch import load_file
from torch import nn


class Mlp(nn.Module):
    def __init__(self, inp, hidden, out):
        super().__init__()
        self.fc1, self.fc2 = nn.Linear(inp, hidden), nn.Linear(hidden, out)

    def forward(self, x):
        return self.fc2(F.silu(self.fc1(x)))


class Block(nn.Module):
    def __init__(self, width, heads, mlp_ratio):
        super().__init__()
        self.heads = heads
        self.qkv, self.out = nn.Linear(width, 3 * width), nn.Linear(width, width)
        self.mlp = Mlp(width, width * mlp_ratio, width)
        self.ada = nn.Linear(width, 6 * width)
        nn.init.zeros_(self.ada.weight)
        nn.init.zeros_(self.ada.bias)

    def attention(self, h):
        b, t, w = h.shape
        q, k, v = self.qkv(h).view(b, t, 3, self.heads, w // self.heads).permute(2, 0, 3, 1, 4)
        y = F.scaled_dot_product_attention(q, k, v)
        return self.out(y.transpose(1, 2).reshape(b, t, w))

    def forward(self, x, c):
        shift1, scale1, gate1, shift2, scale2, gate2 = self.ada(c).unsqueeze(1).chunk(6, dim=-1)
        h = F.layer_norm(x, x.shape[-1:], eps=1e-6) * (1 + scale1) + shift1
        x = x + gate1 * self.attention(h)
        h = F.layer_norm(x, x.shape[-1:], eps=1e-6) * (1 + scale2) + shift2
        return x + gate2 * self.mlp(h)


class Dit(nn.Module):
    def __init__(self, m):
        super().__init__()
        w = m["dit_width"]
        self.freq = max(w, 32)
        self.action_in = nn.Linear(m["action_dim"], w)
        self.pos = nn.Parameter(torch.randn(m["chunk_len"], w) * 0.02)
        self.time = Mlp(self.freq, w, w)
        self.cond_in = nn.Linear(m["obs_embed_dim"], w)
        self.blocks = nn.ModuleList(Block(w, m["dit_heads"], m["dit_mlp_ratio"]) for _ in range(m["dit_depth"]))
        self.final_ada, self.action_out = nn.Linear(w, 2 * w), nn.Linear(w, m["action_dim"])
        for layer in (self.final_ada, self.action_out):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)
        half = self.freq // 2
        self.register_buffer("freqs", torch.exp(-math.log(10_000.0) * torch.arange(half) / half))

    def forward(self, a, tau, emb):
        args = (tau * 1000.0)[:, None] * self.freqs[None]
        c = F.silu(self.time(torch.cat([args.cos(), args.sin()], dim=1)) + self.cond_in(emb))
        x = self.action_in(a) + self.pos
        for block in self.blocks:
            x = block(x, c)
        shift, scale = self.final_ada(c).unsqueeze(1).chunk(2, dim=-1)
        return self.action_out(F.layer_norm(x, x.shape[-1:], eps=1e-6) * (1 + scale) + shift)


class Policy(nn.Module):
    def __init__(self, m, kind):
        super().__init__()
        self.kind = kind
        self.encoder = Mlp(m["obs_dim"], m["encoder"]["hidden"], m["obs_embed_dim"])
        if kind == "mars":
            self.scheduler = Mlp(m["obs_embed_dim"], m["scheduler_hidden"], m["action_dim"])
        self.velocity = Dit(m)

    def weights(self, emb):
        if self.kind == "mars":
            return torch.sigmoid(self.scheduler(emb))
        return torch.full((emb.shape[0], self.velocity.action_out.out_features), 1.0 if self.kind == "fm" else 0.0)


def losses(policy, batch, lambda_rec, lambda_div):
    obs, hist, a1, nbr_hist, s_next = batch
    b = obs.shape[0]
    emb = policy.encoder(obs)
    w = policy.weights(emb)[:, None, :]
    eps = torch.randn_like(a1)
    a0 = (1 - w) * hist + w * eps
    tau = torch.rand(b)
    a_tau = (1 - tau[:, None, None]) * a0 + tau[:, None, None] * a1
    if policy.kind == "fm":
        v = policy.velocity(a_tau, tau, emb)
        return F.mse_loss(v, a1 - a0)
    # L_rec: one Euler step from a source built with w detached, in the same DiT call as L_fm's.
    a0_d = (1 - w.detach()) * hist + w.detach() * eps
    v = policy.velocity(torch.cat([a_tau, a0_d]), torch.cat([tau, torch.zeros(b)]), torch.cat([emb, emb]))
    loss = F.mse_loss(v[:b], a1 - a0)
    per_dim = (a0_d + v[b:] - a1).abs().mean(dim=1)
    loss = loss + lambda_rec * (per_dim * (1 - w.detach()[:, 0, :])).mean()
    if policy.kind == "mars":
        own = (1 - w) * hist + w * torch.randn_like(a1)
        others = (1 - w[:, None]) * nbr_hist + w[:, None] * torch.randn_like(nbr_hist)
        spread = (others - own[:, None]).abs().mean(dim=(1, 2))
        loss = loss + lambda_div * F.relu(s_next - spread).mean()
    return loss


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dir")
    ap.add_argument("--kind", default="mars", choices=["mars", "fm", "a2a"])
    ap.add_argument("--epochs", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    cfg = json.load(open(f"{args.dir}/config.json"))
    m, t = cfg["model"], cfg["train"]
    data = load_file(f"{args.dir}/samples.safetensors")
    obs, hist, nxt, nbrs, s_next = (data[k] for k in ("obs", "history", "next", "neighbours", "s_next"))
    nbrs = nbrs.long()
    policy = Policy(m, args.kind)
    decay = [p for n, p in policy.named_parameters() if p.dim() >= 2 and not n.endswith("pos")]
    rest = [p for n, p in policy.named_parameters() if not (p.dim() >= 2 and not n.endswith("pos"))]
    opt = torch.optim.AdamW(
        [{"params": decay, "weight_decay": t["weight_decay"]}, {"params": rest, "weight_decay": 0.0}],
        lr=t["lr"], eps=1e-8)
    n, bs = obs.shape[0], t["batch_size"]
    for epoch in range(args.epochs):
        start, total, batches = time.perf_counter(), 0.0, 0
        for idx in torch.randperm(n).split(bs):
            if len(idx) < 2:
                continue
            batch = (obs[idx], hist[idx], nxt[idx], hist[nbrs[idx]], s_next[idx])
            loss = losses(policy, batch, t["lambda_rec"], t["lambda_div"])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total, batches = total + loss.item(), batches + 1
        seconds = time.perf_counter() - start
        print(json.dumps({"epoch": epoch, "seconds": seconds, "loss": total / max(batches, 1)}), flush=True)


if __name__ == "__main__":
    main()
