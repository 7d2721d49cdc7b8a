"""Python package set-up of rths_bench (ament_python)."""

from setuptools import find_packages, setup

package_name = 'rths_bench'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='rths maintainers',
    maintainer_email='maintainers@rths.dev',
    description=open('package.xml').read().split('<description>')[1].split('</description>')[0],
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        # `rths bench ...`: rths_bringup's `rths` command finds these modules here (it sits
        # below this package and may not import it); each has register(commands, benches).
        'rths.cli': [
            'bench_loop = rths_bench.bench_loop',
            'bench_faults = rths_bench.bench_faults',
            'bench_distributed = rths_bench.bench_distributed',
            'bench_adaptive = rths_bench.bench_adaptive',
            'rths_benchmark = rths_bench.rths_benchmark',
            'bench_site = rths_bench.bench_site',
            'bench_monitor = rths_bench.bench_monitor',
            'bench_lab = rths_bench.bench_lab',
            'bench_discrepancy_v3 = rths_bench.bench_discrepancy_v3',
            'bench_discrepancy_unseen = rths_bench.bench_discrepancy_unseen',
            'bench_identification = rths_bench.bench_identification',
            'marths = rths_bench.marths',
            'marths_fidelity = rths_bench.marths_fidelity',
            'bench_discrepancy_rths = rths_bench.bench_discrepancy_rths',
            'linkemu = rths_bench.linkemu',
        ],
    },
)
