// B-Human's CompiledNN on one of dribble's networks: the peer in the engine comparison
// (scripts/compiled-nn, models/dribble_models/compiled_nn.py). Not part of the build or the
// suite: `scripts/setup --compiled-nn` compiles it against the library.
//
//   compiled_nn_forward MODEL.h5 --isa ssse3|sse4.2|avx2+fma [--steps N]
//                       [--inputs FILE] [--outputs FILE]
//
// MODEL.h5 is the network in Keras 2's HDF5 layout (dribble_models.compiled_nn writes it from
// the policy's ONNX file). --inputs holds every input tensor's float32 values one after the
// other, in the model's input order (channels last); without it every input is a fixed
// pattern. After one warm-up pass, the outputs of that pass go to --outputs as float32, then
// --steps passes are timed one by one (CLOCK_MONOTONIC) and the line
//   compiled_nn steps=N min_us=.. median_us=.. p99_us=..
// is printed. Under callgrind, runs with --steps 1 and --steps 11 differ by ten passes, as
// `cross/count` measures dribble-controller.
#include <CompiledNN/CompiledNN.h>
#include <CompiledNN/Model.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

namespace
{
  [[noreturn]] void usage(const std::string& problem)
  {
    std::cerr << "compiled_nn_forward: " << problem << "\n"
              << "usage: compiled_nn_forward MODEL.h5 --isa ssse3|sse4.2|avx2+fma [--steps N] "
                 "[--inputs FILE] [--outputs FILE]\n";
    std::exit(2);
  }

  NeuralNetwork::CompilationSettings settings_for(const std::string& isa)
  {
    NeuralNetwork::CompilationSettings settings;
    settings.useX64 = true;
    if(isa == "ssse3")
    {
      settings.useSSE42 = false;
      settings.useAVX2 = false;
      settings.useFMA3 = false;
    }
    else if(isa == "sse4.2")
    {
      settings.useSSE42 = true;
      settings.useAVX2 = false;
      settings.useFMA3 = false;
    }
    else if(isa == "avx2+fma")
    {
      settings.useSSE42 = true;
      settings.useAVX2 = true;
      settings.useFMA3 = true;
    }
    else
      usage("unknown --isa " + isa);
    return settings;
  }

  double now_us()
  {
    timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return static_cast<double>(t.tv_sec) * 1e6 + static_cast<double>(t.tv_nsec) / 1e3;
  }
}

int main(int argc, char* argv[])
{
  if(argc < 2)
    usage("no model");
  const std::string model_path = argv[1];
  std::string isa = "sse4.2", inputs_path, outputs_path;
  long steps = 1;
  for(int i = 2; i < argc; ++i)
  {
    const std::string flag = argv[i];
    if(i + 1 >= argc)
      usage(flag + " needs a value");
    const std::string value = argv[++i];
    if(flag == "--isa")
      isa = value;
    else if(flag == "--steps")
    {
      char* end = nullptr;
      steps = std::strtol(value.c_str(), &end, 10);
      if(*end != '\0' || steps < 1)
        usage("--steps takes a whole number from 1");
    }
    else if(flag == "--inputs")
      inputs_path = value;
    else if(flag == "--outputs")
      outputs_path = value;
    else
      usage("unknown option " + flag);
  }

  std::ifstream probe(model_path, std::ios::binary);
  if(!probe)
    usage("cannot open " + model_path);
  probe.close();
  NeuralNetwork::Model model(model_path);
  NeuralNetwork::CompiledNN network;
  network.compile(model, settings_for(isa));
  if(!network.valid())
  {
    std::cerr << "compiled_nn_forward: CompiledNN could not compile " << model_path << "\n";
    return 1;
  }

  std::vector<float> values;
  if(!inputs_path.empty())
  {
    std::ifstream file(inputs_path, std::ios::binary | std::ios::ate);
    if(!file)
      usage("cannot open " + inputs_path);
    const std::streamsize bytes = file.tellg();
    values.resize(static_cast<std::size_t>(bytes) / sizeof(float));
    file.seekg(0);
    file.read(reinterpret_cast<char*>(values.data()), bytes);
  }
  std::size_t offset = 0;
  for(std::size_t i = 0; i < network.numOfInputs(); ++i)
  {
    NeuralNetwork::TensorXf& input = network.input(i);
    for(std::size_t k = 0; k < input.size(); ++k, ++offset)
      input[k] = inputs_path.empty() ? static_cast<float>((offset * 37 + 11) % 256) / 255.f : 0.f;
    if(!inputs_path.empty())
    {
      if(offset > values.size())
        usage(inputs_path + " holds " + std::to_string(values.size()) + " values, the inputs need more");
      std::memcpy(input.data(), values.data() + offset - input.size(), input.size() * sizeof(float));
    }
  }
  if(!inputs_path.empty() && offset != values.size())
    usage(inputs_path + " holds " + std::to_string(values.size()) + " values, the inputs take " +
          std::to_string(offset));

  network.apply();
  if(!outputs_path.empty())
  {
    std::ofstream file(outputs_path, std::ios::binary);
    for(std::size_t i = 0; i < network.numOfOutputs(); ++i)
    {
      const NeuralNetwork::TensorXf& output = network.output(i);
      file.write(reinterpret_cast<const char*>(output.data()),
                 static_cast<std::streamsize>(output.size() * sizeof(float)));
    }
  }

  std::vector<double> times(static_cast<std::size_t>(steps));
  for(double& time : times)
  {
    const double start = now_us();
    network.apply();
    time = now_us() - start;
  }
  std::sort(times.begin(), times.end());
  const auto at = [&](double share) {
    return times[std::min(times.size() - 1, static_cast<std::size_t>(share * static_cast<double>(times.size())))];
  };
  std::printf("compiled_nn steps=%ld min_us=%.2f median_us=%.2f p99_us=%.2f\n", steps, times.front(), at(0.5),
              at(0.99));
  return 0;
}
