"""Fine-tune the shipped level head on the cells' colour images of mosaics (research, issue #35)."""
import math, sys, time
import numpy as np, torch
from references.learned_single import levels as L, train as recipe
from torch_modulo.singleshot.learned import edge_features, load_model
steps, lr, out = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
torch.manual_seed(21); torch.set_num_threads(2)
options = recipe.parse_args(["--crop", "128", "--batch", "6", "--scene-exposure", "0.5", "--cells", "1.0"])
rng = np.random.default_rng(21)
scenes = recipe.load_train_scenes(options.scene_side, options.data)
refs = [recipe.exposure_references(s) for s in scenes]
edge = load_model()
net = L.load("torch_modulo/singleshot/weights/levels.pt", edge).train()
opt = torch.optim.Adam(net.head.parameters(), lr=lr)
start, smooth = time.perf_counter(), None
for step in range(steps):
    for g in opt.param_groups:
        g["lr"] = lr * 0.5 * (1 + math.cos(math.pi * step / steps))
    wrapped, counts = recipe.make_batch(scenes, options.batch, options.crop, rng, options, refs)
    x = edge_features(wrapped, 8)
    with torch.no_grad():
        d2 = edge.encode(x)[1]
    loss = L.level_loss(net(x, d2), counts)
    opt.zero_grad(); loss.backward(); opt.step()
    smooth = float(loss) if smooth is None else 0.98 * smooth + 0.02 * float(loss)
    if (step + 1) % 100 == 0:
        print(f"step {step + 1} loss {smooth:.4f} {time.perf_counter() - start:.0f}s", flush=True)
head = {k: v.detach().half() for k, v in net.head.state_dict().items()}
torch.save({"config": edge.config, "state": {k: v.half() for k, v in edge.state_dict().items()}, "head": head}, out)
print("saved", out)
