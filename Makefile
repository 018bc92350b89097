# The two set-up commands of the README: `make demo` and `make test`.
.PHONY: setup demo test

setup:
	./scripts/setup.sh

demo: setup
	mkdir -p out
	.venv/bin/pghm render assets/real_avatar.pt --motion assets/motion/mixamo_walk_69f.bvh --orbit --out out/demo.mp4
	.venv/bin/pghm render assets/real_avatar.pt --motion assets/motion/mixamo_walk_69f.bvh --start 0.5 --out out/demo.png
	@echo "wrote out/demo.mp4 and out/demo.png; open the live viewer with .venv/bin/pghm-view (needs a display)"

test: setup
	.venv/bin/python -m pytest -q -n 2 --dist loadfile --durations=15
