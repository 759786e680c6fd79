import pytest
import torch

# One intra-op thread per test process: tiny kernels (4×4 convs) are ~1000x slower when
# two OpenMP threads contend with the other xdist worker on a 2-core machine.
torch.set_num_threads(1)


@pytest.fixture(params=[torch.float32, torch.float64], ids=["f32", "f64"])
def dtype(request):
    return request.param


@pytest.fixture
def gen():
    return torch.Generator().manual_seed(0)


#: Every device the module tests run on: the CPU, and CUDA where present.
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(params=DEVICES)
def device(request):
    return torch.device(request.param)
