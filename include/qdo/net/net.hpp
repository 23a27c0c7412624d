// The LibTorch network decoder's entry point that needs no LibTorch headers: programs linked with
// qdo_net (the qdo tool, the tests, the benches when QDO_TORCH is on) call register_torch_network()
// once, after which make_network_decoder (network_decoder.hpp) builds Res-UNets (resunet.hpp).
#pragma once

namespace qdo {

// Registers the LibTorch Res-UNet factory; sets LibTorch's intra-op threads to the machine's
// hardware threads (Debian's LibTorch starts with one), or to QDO_TORCH_THREADS when set.
void register_torch_network();

}  // namespace qdo
