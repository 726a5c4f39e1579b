# btfvq: the two commands a new user needs are `make demo` and `make test`.
# Every target installs what is missing first (Debian packages; needs root or sudo).

BUILD      ?= build
BUILD_REL  ?= build-release
JOBS       ?= $(shell nproc)
BENCH_ARGS ?=
PREFIX     ?= /usr/local
DEB_PACKAGES = build-essential cmake pkg-config \
  pocl-opencl-icd opencl-c-headers opencl-clhpp-headers ocl-icd-opencl-dev clinfo \
  libopenimageio-dev libspdlog-dev nlohmann-json3-dev libcpp-httplib-dev doctest-dev \
  libsqlite3-dev libarchive-dev libeigen3-dev libzstd-dev unzip curl python3 python3-matplotlib \
  pybind11-dev python3-dev python3-numpy python3-pytest \
  chromium fonts-liberation slurm-wlm munge

.PHONY: deps build programs build-release test demo bench clean install

deps:
	@bash scripts/install-deps.sh $(DEB_PACKAGES)

$(BUILD)/CMakeCache.txt:
	cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DBTFVQ_WERROR=ON

build: deps $(BUILD)/CMakeCache.txt
	cmake --build $(BUILD) -j $(JOBS)

# Only what the demo runs: a newcomer's first `make demo` need not wait for every test and bench.
programs: deps $(BUILD)/CMakeCache.txt
	cmake --build $(BUILD) -j $(JOBS) --target btfvq-cli btfvq-server

build-release: deps
	cmake -S . -B $(BUILD_REL) -DCMAKE_BUILD_TYPE=Release -DBTFVQ_NATIVE=ON -DBTFVQ_WERROR=OFF -DBTFVQ_TESTS=OFF
	cmake --build $(BUILD_REL) -j $(JOBS)

test: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900

demo: programs
	@bash scripts/demo.sh $(BUILD)/bin

bench: build-release
	@bash bench/run.sh $(BUILD_REL)/bin $(BENCH_ARGS)

install: build-release
	cmake --install $(BUILD_REL) --prefix $(PREFIX)

clean:
	rm -rf $(BUILD) $(BUILD_REL)
