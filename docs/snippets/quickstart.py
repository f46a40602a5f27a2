import bptsb_ros as bp

cfg = bp.load_config("lissajous_single", {"sim_time": 20})  # the packaged config, 20 s of training
result = bp.train(cfg, callback=lambda update, loss: print(f"update {update}: loss {loss:.4f} m²"))
traj = bp.simulate(result.agent, steps=500, loop="closed", state=result.state)  # 5 s under the fitted FL
ev = result.metrics["evaluation"]
print(f"CMP error {ev['trajectory_mse']:.4f} m² (target mean square {ev['target_mean_square']:.4f} m²)")
print("closed loop, CMP after 5 s [m]:", traj.reference_point()[-1])
