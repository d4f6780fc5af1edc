# Two commands do everything on a fresh Debian machine (see README.md):
#   make demo   - install, bake the demo site if it is not baked, serve it with the simulated sky
#   make test   - install, then run every test (Python, headless Chromium, lint)
# Everything else here is what those two need.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
DEMO_BUILD := build/demo

.PHONY: demo test setup python-deps node-deps chromium redis lint clean

# The demo is baked at draft quality (about 3 minutes on two cores, 1.7 GB): the final quality
# takes tens of minutes and 5.0 GB (README.md says how to bake it).
demo: setup
	@if [ ! -f $(DEMO_BUILD)/manifest.json ]; then \
		echo "Baking the demo site into $(DEMO_BUILD) at draft quality (first run only)..."; \
		$(BIN)/daylit bake scenes/demo -o $(DEMO_BUILD) --quality draft; \
	fi
	@if [ ! -d $(DEMO_BUILD)/coarse ]; then \
		echo "Adding a coarse start to a demo baked before 2026-11-25 (docs/web.md, Slow links)..."; \
		$(BIN)/python -m bake.coarse $(DEMO_BUILD); \
	fi
	$(BIN)/daylit serve $(DEMO_BUILD)

test: setup
	$(BIN)/ruff check .
	$(BIN)/python -m pytest

setup: python-deps node-deps chromium redis

python-deps: $(VENV)/.installed
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --disable-pip-version-check -e '.[dev]'
	touch $@

node-deps: node_modules/.installed
node_modules/.installed: package.json package-lock.json
	npm ci --no-audit --no-fund --loglevel=error
	touch $@

# Debian's Chromium drives the browser tests (never a test tool's own download).
chromium:
	@command -v chromium >/dev/null 2>&1 || { \
		if [ "$$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi; \
		echo "Installing Debian's chromium for the browser tests..."; \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq chromium >/dev/null; }

# Debian's Redis: the broker of several fan-out workers (docs/server.md), started by its tests.
redis:
	@command -v redis-server >/dev/null 2>&1 || { \
		if [ "$$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi; \
		echo "Installing Debian's redis-server for the broker tests..."; \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq redis-server >/dev/null; }

lint: python-deps
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) node_modules build
